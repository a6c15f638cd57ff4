"""Survey and image measurements simulated on the exact models of vendors' metadata: a stand-in
for a lab's own measurements when only the metadata files are at hand (no rasters, no survey).

Each image's metadata is taken to be off by a horizontal ground shift (east, north metres of the
local frame at the scene; drawn with ``shift_sigma_m`` per axis), the way a satellite's direct
georeferencing misses by a few metres: a ground point G is imaged by image i where its exact model
(every correction on) sees ``G - shift_i``. Points are drawn over the first image (image
positions uniform within ``MARGIN`` of its borders, ellipsoidal heights uniform over
``height_range_m``: :func:`height_range` gives the RPC's height offset +- half its scale) and kept where every
image sees them; measurements get Gaussian noise of ``noise_px`` and the surveyed coordinates
of control and check points Gaussian noise of ``survey_sigma_m`` (east, north, up).

The truth (every point's true coordinates, each image's shift) comes back beside the tables so
that a tutorial or a test can say how far an adjustment lands from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from solver.geometry.geodesy import LocalFrame, ecef_to_geodetic, geodetic_to_ecef
from solver.geometry.rpc import RPC
from solver.sensors.linescan import LinescanModel

MARGIN = 0.05  # fraction of the first image's lines and columns left free at each border
DEFAULT_HEIGHT_M = 0.0  # ellipsoidal height of the points when the product has no RPC
CANDIDATES_FACTOR = 4  # points drawn per point wanted (the rest fall outside another image)


@dataclass(frozen=True)
class SimulatedMeasurements:
    """Job points (roles gcp, check, tie; surveyed coordinates with noise, sigmas in metres),
    observations (image, point, line, column, sigma_px), and the truth: the points' true
    (lon, lat, h) and each image's ground shift (east, north metres)."""

    points: list[dict[str, Any]]
    observations: list[dict[str, Any]]
    truth: dict[str, Any]


def height_range(rpc: RPC | None) -> tuple[float, float]:
    """Ellipsoidal heights (m) of the simulated points: the RPC's height offset +- half its
    scale (the terrain the vendor fitted it over), or ``DEFAULT_HEIGHT_M`` without an RPC."""
    if rpc is None:
        return DEFAULT_HEIGHT_M, DEFAULT_HEIGHT_M
    return rpc.height_off - 0.5 * rpc.height_scale, rpc.height_off + 0.5 * rpc.height_scale


def simulate_measurements(
    models: list[LinescanModel],
    image_ids: list[str],
    height_range_m: tuple[float, float],
    gcps: int,
    checks: int,
    ties: int,
    shift_sigma_m: float = 3.0,
    noise_px: float = 0.3,
    survey_sigma_m: float = 0.1,
    seed: int = 1,
) -> SimulatedMeasurements:
    """Points and measurements seen by the exact ``models`` (module docstring; heights in
    metres, shifts and sigmas in metres, noise in pixels); ``ValueError`` when fewer points than
    asked fall inside every image."""
    if min(gcps, checks, ties) < 0 or gcps + checks + ties == 0:
        raise ValueError("the numbers of control, check and tie points must be >= 0, and not all 0")
    rng = np.random.default_rng(seed)
    first = models[0]
    n_want = gcps + checks + ties
    n = CANDIDATES_FACTOR * n_want
    lines = rng.uniform(MARGIN, 1 - MARGIN, n) * (first.lines - 1)
    cols = rng.uniform(MARGIN, 1 - MARGIN, n) * (first.columns - 1)
    seen = first.image_to_ground(lines, cols, rng.uniform(*height_range_m, n))
    frame = LocalFrame.at_centroid(geodetic_to_ecef(seen))
    shifts = np.column_stack([rng.normal(0.0, shift_sigma_m, (len(models), 2)), np.zeros(len(models))])

    def moved(g: np.ndarray, enu: np.ndarray) -> np.ndarray:
        return ecef_to_geodetic(frame.to_ecef(frame.to_lgs(geodetic_to_ecef(g)) + enu))

    truth = moved(seen, shifts[0])  # image 0 sees `seen` where the truth is seen + shift_0
    images = [np.column_stack([lines, cols])]
    for m, shift in zip(models[1:], shifts[1:]):
        images.append(m.ground_to_image(moved(truth, -shift)))
    inside = np.ones(n, bool)
    for m, lc in zip(models, images):
        inside &= np.all(np.isfinite(lc), axis=1) & (lc[:, 0] >= 0) & (lc[:, 0] <= m.lines - 1)
        inside &= (lc[:, 1] >= 0) & (lc[:, 1] <= m.columns - 1)
    keep = np.flatnonzero(inside)
    if keep.size < n_want:
        raise ValueError(f"only {keep.size} of {n} simulated points fall inside every image; ask for fewer than {n_want}")
    keep = keep[:n_want]
    roles = ["gcp"] * gcps + ["check"] * checks + ["tie"] * ties
    names = [f"G{k + 1:02d}" for k in range(gcps)] + [f"C{k + 1:02d}" for k in range(checks)] + [f"T{k + 1:02d}" for k in range(ties)]
    surveyed = moved(truth[keep], rng.normal(0.0, survey_sigma_m, (n_want, 3)))
    points: list[dict[str, Any]] = []
    for name, role, xyz in zip(names, roles, surveyed):
        if role == "tie":
            points.append({"id": name, "role": "tie"})
        else:
            points.append({"id": name, "role": role, "coordinates": [float(v) for v in xyz], "sigma_m": [survey_sigma_m] * 3})
    observations = []
    for image_id, lc in zip(image_ids, images):
        noisy = lc[keep] + rng.normal(0.0, noise_px, (n_want, 2))
        observations += [{"image": image_id, "point": name, "line": float(v[0]), "column": float(v[1]), "sigma_px": noise_px}
                         for name, v in zip(names, noisy)]
    return SimulatedMeasurements(points, observations, {
        "points": {name: [float(v) for v in xyz] for name, xyz in zip(names, truth[keep])},
        "image_shifts_en_m": {image_id: [float(s[0]), float(s[1])] for image_id, s in zip(image_ids, shifts)},
        "seed": seed, "noise_px": noise_px, "survey_sigma_m": survey_sigma_m, "shift_sigma_m": shift_sigma_m,
    })
