"""Synthetic rasters of simulated images (``pba simulate ... --raster``): what the camera would
record of a textured ground with marked targets, in the image's raw geometry (line, column;
pixel centres at integer positions, no georeferencing).

The ground is a smooth texture (sums of sines of east and north, wavelengths 25-60 ground
sample distances, grey levels 70-130) with a bright Gaussian target (peak +120, sigma 1.5 GSD)
at the true position of every control and check point. Each pixel takes the value of the ground
point its centre sees: the exact rays (:meth:`ImageGeometry.image_to_ground` on the terrain) on
a grid every ``step`` pixels, interpolated bilinearly between (the mapping is smooth: well under
0.01 px for the default step of 8 on the preset scenes).

``texture="rich"`` (``pba simulate ... --raster --raster-texture rich``, for image matching)
adds a fine random texture fixed on the ground (:data:`RICH_WAVES` plane waves of random
direction and phase, wavelengths 3-40 GSD, the same in every image) and makes the views differ
radiometrically (the texture's scale is the scene's smallest GSD, :func:`scene_gsd`, the
same for every view; the smooth default follows each image's own GSD, as it always did): each image gets its own gain (0.8-1.2), offset (-15..15 grey levels) and
Gaussian noise (sigma ``noise_dn``, 2 grey levels by default), drawn from ``seed`` and the
image's index. It is written as 16-bit (``uint16``, grey levels x 64), so that 8-16 bit input is
exercised.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from solver.geometry.geodesy import LocalFrame

TARGET_PEAK = 120.0
TARGET_SIGMA_GSD = 1.5
RICH_WAVES = 48
RICH_WAVELENGTHS_GSD = (3.0, 40.0)
RICH_SCALE_16BIT = 64


def _axis(n: int, step: int) -> np.ndarray:
    a = np.arange(0, n, step, dtype=float)
    return a if a[-1] == n - 1 else np.append(a, n - 1)


def _bilinear(grid: np.ndarray, ls: np.ndarray, cs: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Values of ``grid`` (on nodes ``ls`` x ``cs``) at every (row, col) of the full raster."""
    i = np.clip(np.searchsorted(ls, rows, side="right") - 1, 0, len(ls) - 2)
    j = np.clip(np.searchsorted(cs, cols, side="right") - 1, 0, len(cs) - 2)
    fr = ((rows - ls[i]) / (ls[i + 1] - ls[i]))[:, None]
    fc = ((cols - cs[j]) / (cs[j + 1] - cs[j]))[None, :]
    a, b = grid[np.ix_(i, j)], grid[np.ix_(i, j + 1)]
    c, d = grid[np.ix_(i + 1, j)], grid[np.ix_(i + 1, j + 1)]
    return a * (1 - fr) * (1 - fc) + b * (1 - fr) * fc + c * fr * (1 - fc) + d * fr * fc


def _rich_texture(e: np.ndarray, n: np.ndarray, gsd: float) -> np.ndarray:
    """The fine ground texture (grey levels, zero mean, std ~ 20) at east/north metres."""
    rng = np.random.default_rng(20261125)  # one texture for every image of every scene
    lam = gsd * np.exp(rng.uniform(*np.log(RICH_WAVELENGTHS_GSD), RICH_WAVES))
    theta = rng.uniform(0, 2 * np.pi, RICH_WAVES)
    phase = rng.uniform(0, 2 * np.pi, RICH_WAVES)
    amp = np.sqrt(lam / gsd)
    amp *= 20.0 * np.sqrt(2.0 / np.sum(amp**2))
    out = np.zeros_like(e)
    for k in range(RICH_WAVES):
        out += amp[k] * np.sin(2 * np.pi * (e * np.cos(theta[k]) + n * np.sin(theta[k])) / lam[k] + phase[k])
    return out


def scene_gsd(scene, frame: LocalFrame) -> float:
    """The smallest ground sample distance (m) at the centre of the scene's images, on the terrain."""
    out = []
    for geom in scene.images:
        cam = geom.camera
        l0, c0 = (cam.lines - 1) / 2.0, (cam.columns - 1) / 2.0
        g = frame.to_lgs(geom.image_to_ground(np.array([l0, l0, l0 + 1]), np.array([c0, c0 + 1, c0]), terrain=scene.terrain))
        out.append(min(np.hypot(*(g[1, :2] - g[0, :2])), np.hypot(*(g[2, :2] - g[0, :2]))))
    return float(min(out))


def render_image(scene, index: int, step: int = 8, texture: str = "smooth", seed: int = 0, noise_dn: float = 2.0) -> np.ndarray:
    """(lines, columns) raster of simulated image ``index`` of ``scene``: uint8 for the default
    smooth texture, uint16 for ``texture="rich"`` (module docstring)."""
    geom = scene.images[index]
    cam = geom.camera
    frame = LocalFrame.at_centroid(np.array([p.ecef_m for p in scene.points]))
    ls, cs = _axis(cam.lines, step), _axis(cam.columns, step)
    ll, cc = np.meshgrid(ls, cs, indexing="ij")
    ground = frame.to_lgs(geom.image_to_ground(ll.ravel(), cc.ravel(), terrain=scene.terrain))
    e_grid = ground[:, 0].reshape(ll.shape)
    n_grid = ground[:, 1].reshape(ll.shape)
    gsd = float(np.median(np.hypot(np.diff(e_grid, axis=1), np.diff(n_grid, axis=1)))) / step
    if texture == "rich":  # one ground texture for every view: its scale must not follow the image's GSD
        gsd = scene_gsd(scene, frame)
    rows, cols = np.arange(cam.lines, dtype=float), np.arange(cam.columns, dtype=float)
    e = _bilinear(e_grid, ls, cs, rows, cols)
    n = _bilinear(n_grid, ls, cs, rows, cols)
    return _ground_grey(scene, frame, e, n, gsd, texture, [seed, index], noise_dn)


def _ground_grey(scene, frame: LocalFrame, e: np.ndarray, n: np.ndarray, gsd: float, texture: str, seed: list[int], noise_dn: float) -> np.ndarray:
    """The ground's grey levels at east/north metres ``e``, ``n`` of ``frame`` (module
    docstring), with the radiometry of one view (``seed``) for the rich texture."""
    tau = 2 * np.pi
    value = 100.0 + 15.0 * np.sin(tau * e / (37 * gsd)) * np.cos(tau * n / (53 * gsd)) + 12.0 * np.sin(tau * (e + n) / (25 * gsd))
    sigma = TARGET_SIGMA_GSD * gsd
    for p in scene.points:
        if p.role not in ("gcp", "check"):
            continue
        te, tn, _ = frame.to_lgs(p.ecef_m)
        near = (np.abs(e - te) < 6 * sigma) & (np.abs(n - tn) < 6 * sigma)
        if near.any():
            value[near] += TARGET_PEAK * np.exp(-((e[near] - te) ** 2 + (n[near] - tn) ** 2) / (2 * sigma**2))
    if texture == "rich":
        rng = np.random.default_rng(seed)
        gain, offset = rng.uniform(0.8, 1.2), rng.uniform(-15.0, 15.0)
        value = gain * (value + _rich_texture(e, n, gsd)) + offset + rng.normal(0.0, noise_dn, value.shape)
        return np.clip(np.rint(value * RICH_SCALE_16BIT), 0, 65535).astype(np.uint16)
    if texture != "smooth":
        raise ValueError(f"unknown texture {texture!r} (smooth or rich)")
    return np.clip(np.rint(value), 0, 255).astype(np.uint8)


def render_ortho(scene, lon_deg: np.ndarray, lat_deg: np.ndarray, seed: int = 0, noise_dn: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """A true orthophoto of the scene's ground and its DEM on the geographic grid ``lon_deg``
    (columns, west to east) x ``lat_deg`` (rows, north to south), pixel centres: the rich
    texture of :func:`render_image` (uint16) with radiometry of its own (``seed``), and the
    true terrain's ellipsoidal height (float32 m) at every pixel centre."""
    from solver.geometry.geodesy import geodetic_to_ecef

    frame = LocalFrame.at_centroid(np.array([p.ecef_m for p in scene.points]))
    lon, lat = np.meshgrid(np.asarray(lon_deg, float), np.asarray(lat_deg, float))
    h = scene.terrain.height(lon.ravel(), lat.ravel())
    g = frame.to_lgs(geodetic_to_ecef(np.column_stack([lon.ravel(), lat.ravel(), h])))
    e, n = g[:, 0].reshape(lon.shape), g[:, 1].reshape(lon.shape)
    grey = _ground_grey(scene, frame, e, n, scene_gsd(scene, frame), "rich", [seed, 1_000_003], noise_dn)
    return grey, h.reshape(lon.shape).astype(np.float32)


def write_rasters(scene, job_path: Path, step: int = 8, texture: str = "smooth", seed: int = 0) -> list[Path]:
    """One GeoTIFF per image beside the job: ``<job stem>.<image id>.tif`` (raw geometry)."""
    from rasterio.errors import NotGeoreferencedWarning

    from solver.raster_gate import create_raster

    job_path = Path(job_path)
    stem = job_path.name[:-5] if job_path.name.endswith(".json") else job_path.name
    out = []
    for i, geom in enumerate(scene.images):
        data = render_image(scene, i, step, texture, seed)
        path = job_path.with_name(f"{stem}.{geom.id}.tif")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)  # raw image geometry, as delivered
            with create_raster(path, driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype=data.dtype.name, compress="deflate") as dst:
                dst.write(data, 1)
        out.append(path)
    return out
