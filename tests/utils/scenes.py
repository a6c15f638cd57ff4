"""Model-consistent synthetic scenes: observations generated *by a platform model itself*.

For unit tests (a model must recover its own truth), Monte Carlo checks of the covariance and
benchmarks. This is deliberately not the physical simulator (:mod:`solver.simulate`), which
integrates an orbit independently of every platform model and is what tests model fidelity.

Geometry: an ALOS-like pass (about 692 km high, flying south-south-west at ~7.5 km/s) over a
scene centre (default Presidente Prudente, 22.12 S 51.39 W); ground points are found by
intersecting the rays of chosen pixels with a smooth terrain, so their projections are exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from solver.engine.assemble import kepler_constants
from solver.geometry.geodesy import LocalFrame, ecef_to_geodetic, geodetic_to_ecef
from solver.kernels import N_COEF, platform_state, project, ray
from solver.platforms import ANGLES, ELEMENTS, HELD, coef_index, get_model
from solver.platforms.kepler import AE_M, GM_M3_S2, J2, OMEGA_RAD_S

PRISM_NADIR = {
    "focal_mm": 1999.8630195,
    "pixel_mm": 0.0071,
    "line_time_s": 0.00037,
    "lines": 16000,
    "columns": 14496,
}


@dataclass
class SyntheticImage:
    id: str
    model: str
    pitch_deg: float
    coef: np.ndarray  # true full coefficients
    kc: np.ndarray
    tau_per_line: float
    r0_ecef: np.ndarray
    v0_ecef: np.ndarray


def terrain_height(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Smooth terrain (m above the LGS origin plane), about +-100 m."""
    return 60.0 * np.sin(e / 7000.0) * np.cos(n / 9000.0) + 40.0 * np.sin((e + n) / 13000.0)


def _view_arcs(frame: LocalFrame, pitch_deg: float, altitude_m: float) -> tuple[float, float]:
    """(incidence, arc) in rad of a view pitched ``pitch_deg`` off the platform's own vertical
    at ``altitude_m`` over a sphere of the scene centre's geocentric radius: the angle of the
    line of sight to the scene's vertical (the pitch as the scene's frame sees it) and the arc
    from the platform's nadir to the scene centre (both signed as the pitch; law of sines)."""
    radius = float(np.linalg.norm(frame.origin_ecef_m))
    eta = math.radians(pitch_deg)
    incidence = math.asin((radius + altitude_m) / radius * math.sin(eta))
    return incidence, incidence - eta


def incidence_deg(frame: LocalFrame, pitch_deg: float, altitude_m: float = 692e3) -> float:
    """The scene-frame pitch (deg) of a camera mounted ``pitch_deg`` off its platform's vertical
    (23.8 deg: 26.6 deg at the scene): the angle a scene's true attitude is written with."""
    return math.degrees(_view_arcs(frame, pitch_deg, altitude_m)[0])


def _state_for_pass(frame: LocalFrame, t_mid: float, pitch_deg: float, altitude_m: float, heading_deg: float, along_offset_m: float = 0.0,
                    satellite: bool = False):
    """ECEF position/velocity at line 0 of an image whose middle line looks at the scene centre.

    By default in the scene's tangent plane: the platform ``altitude_m`` above it and
    ``tan(pitch) altitude`` along the track, its velocity in the plane (a flat Earth: the
    platform's own vertical is then 2.8 deg off the scene's for a 23.8 deg view, so the camera
    looks from a mounting the job does not state). ``satellite``: with the camera pitched
    ``pitch_deg`` off the platform's own vertical (a satellite's mounting) and the platform flying
    level, over a sphere of the scene centre's radius: an arc behind the centre for a forward
    view, ahead for a backward one; write the scene-frame attitude with :func:`incidence_deg`."""
    h = math.radians(heading_deg)
    speed = 7560.0 * (6378137.0 + 0.0) / (6378137.0 + altitude_m) * 1.0
    vdir = np.array([math.sin(h), math.cos(h), 0.0])  # east, north
    if satellite:
        up = np.array([0.0, 0.0, 1.0])
        radius = float(np.linalg.norm(frame.origin_ecef_m))
        _incidence, arc = _view_arcs(frame, pitch_deg, altitude_m)
        s_mid = (radius + altitude_m) * (-math.sin(arc) * vdir + math.cos(arc) * up) - radius * up + vdir * along_offset_m
        v = speed * (math.cos(arc) * vdir + math.sin(arc) * up)
    else:
        look_back = math.tan(math.radians(-pitch_deg)) * altitude_m  # backward camera is ahead
        s_mid = vdir * (look_back + along_offset_m) + np.array([0.0, 0.0, altitude_m])
        v = vdir * speed
    s0 = s_mid - v * t_mid
    return frame.to_ecef(s0), frame.vector_to_ecef(v)


def _orbit_relative_angles(frame: LocalFrame, r0, v0, line_time: float, angles, mount_rad: float):
    """Attitude (roll, pitch, yaw) relative to the orbital frame that gives, at the middle line,
    the same rotation as the LGS angles ``angles``: M = Ry(mount) R_att R_orbit."""
    from solver.engine.initialize import _rotating_frame_acceleration, angles_from_matrix
    from solver.kernels import _mount, _orbital_frame, rotation_and_derivatives

    t = line_time * 8000.0
    a = _rotating_frame_acceleration(r0, v0)
    s_e = r0 + v0 * t + 0.5 * a * t * t
    v_e = v0 + a * t
    s = frame.to_lgs(s_e)
    v = frame.vector_to_lgs(v_e)
    c = frame.rotation_ecef_to_lgs @ frame.origin_ecef_m
    r_orb = _orbital_frame(s, v, c)[0]
    m_lgs = rotation_and_derivatives(*angles)[0]
    r_att = _mount(mount_rad).T @ m_lgs @ r_orb.T
    return angles_from_matrix(r_att)


def true_coefficients(model_name: str, frame: LocalFrame, r0: np.ndarray, v0: np.ndarray, line_time: float,
                      angles: tuple[float, float, float], rates: tuple[float, float], options: dict | None = None,
                      mount_rad: float = 0.0) -> np.ndarray:
    """Full coefficient vector of ``model_name`` for the given state and attitude (rad, rad/s)."""
    model = get_model(model_name)
    opts = options or {}
    coef = np.zeros(N_COEF)
    tpl = model.tau_per_line(line_time)
    dt_dtau = line_time / tpl
    if model.kind.attitude_in_orbital_frame:
        angles = _orbit_relative_angles(frame, r0, v0, line_time, angles, mount_rad)
    if model.kind.earth_fixed:
        for e in range(3):
            coef[e * 4] = r0[e]
            coef[e * 4 + 1] = v0[e]
    else:
        from solver.engine.initialize import _rotating_frame_acceleration

        a = frame.vector_to_lgs(_rotating_frame_acceleration(r0, v0))
        s = frame.to_lgs(r0)
        v = frame.vector_to_lgs(v0)
        orders = model.effective_orders(opts)
        for e in range(3):
            coef[e * 4] = s[e]
            if orders[e] >= 1:
                coef[e * 4 + 1] = v[e] * dt_dtau
            if orders[e] >= 2:
                coef[e * 4 + 2] = 0.5 * a[e] * dt_dtau**2
    orders = model.effective_orders(opts)
    for e, val in zip(ANGLES, angles):
        coef[coef_index(e, 0)] = val
    ko = orders[ELEMENTS.index("kappa")]
    if ko >= 1:
        coef[coef_index("kappa", 1)] = rates[0] * dt_dtau
    if ko >= 2:
        coef[coef_index("kappa", 2)] = rates[1] * dt_dtau**2
    for e in ANGLES:
        if orders[ELEMENTS.index(e)] == HELD:
            pass  # held values are whatever the caller passes in angles
    return coef


def _obs_consts(cam: dict, line: float, col: float, sigma: float, tpl: float) -> np.ndarray:
    return np.array([line, col, sigma, cam["focal_mm"], cam["pixel_mm"], 0.0, 0.0, (cam["columns"] - 1) / 2.0, tpl])


def ground_point_of_pixel(img: SyntheticImage, cam: dict, line: float, col: float) -> np.ndarray:
    """LGS point on the terrain seen by pixel (line, col) with the true orientation."""
    oc = _obs_consts(cam, line, col, 1.0, img.tau_per_line)
    kind = get_model(img.model).kind.kernel
    s, d = ray(kind, img.coef, img.kc, oc)
    z = 0.0
    for _ in range(20):
        lam = (z - s[2]) / d[2]
        p = s + lam * d
        z_new = float(terrain_height(np.array([p[0]]), np.array([p[1]]))[0])
        if abs(z_new - z) < 1e-6:
            break
        z = z_new
    lam = (z - s[2]) / d[2]
    return s + lam * d


def project_point(img: SyntheticImage, cam: dict, p: np.ndarray, line_guess: float) -> tuple[float, float]:
    kind = get_model(img.model).kind.kernel
    oc = _obs_consts(cam, line_guess, (cam["columns"] - 1) / 2.0, 1.0, img.tau_per_line)
    ok, line, col, *_ = project(kind, img.coef, img.kc, p, oc, False)
    return float(line), float(col)


def single_image_job(
    model: str = "K2",
    n_gcp: int = 14,
    n_check: int = 9,
    noise_px: float = 0.5,
    pitch_deg: float = 0.0,
    seed: int = 0,
    gcp_sigma_m: float | None = None,
    control: str = "weighted",
    approx_error_m: float = 20.0,
    camera: dict | None = None,
    options: dict | None = None,
    noise_seed: int | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A one-image job generated by ``model`` itself, and its truth (coefficients, points).

    ``seed`` draws the geometry, ``noise_seed`` (default: derived from seed) the measurement
    noise, so Monte Carlo runs can keep one geometry and redraw only the noise.
    """
    rng = np.random.default_rng(seed)
    nrng = np.random.default_rng(seed + 7919 if noise_seed is None else noise_seed)
    cam = dict(PRISM_NADIR if camera is None else camera)
    centre = geodetic_to_ecef(np.array([[-51.39, -22.12, 450.0]]))[0]
    frame = LocalFrame.at(centre)
    lt = cam["line_time_s"]
    t_mid = lt * (cam["lines"] - 1) / 2.0
    r0, v0 = _state_for_pass(frame, t_mid, pitch_deg, 692e3, 190.0)
    h = math.radians(190.0)
    kappa0 = math.atan2(-math.cos(h), math.sin(h))
    angles = (math.radians(0.02), math.radians(pitch_deg), kappa0 + math.radians(0.1))
    m = get_model(model)
    mopts = dict(options or {})
    held = {}
    for e in ANGLES:
        if m.effective_orders(mopts)[ELEMENTS.index(e)] == HELD:
            held[e] = math.degrees(angles[ANGLES.index(e)])
            mopts[f"{e}_deg"] = held[e]
    rates = (math.radians(30 / 3600), math.radians(0.05 / 3600))
    n = n_gcp + n_check
    # well spread pixels: jittered grid
    g = int(math.ceil(math.sqrt(n)))
    pix = []
    for i in range(g):
        for j in range(g):
            pix.append(((i + 0.2 + 0.6 * rng.random()) / g * (cam["lines"] - 1), (j + 0.2 + 0.6 * rng.random()) / g * (cam["columns"] - 1)))
    rng.shuffle(pix)
    pix = pix[:n]
    # The solver's LGS is centred on the control points, which depend on the truth: iterate
    # until the truth is expressed in exactly the frame the solver will build.
    for _ in range(12):
        coef = true_coefficients(model, frame, r0, v0, lt, angles, rates, mopts, math.radians(pitch_deg))
        img = SyntheticImage("img-1", model, pitch_deg, coef, kepler_constants(m, frame, pitch_deg), m.tau_per_line(lt), r0, v0)
        pts_lgs = np.array([ground_point_of_pixel(img, cam, l, c) for l, c in pix])
        ecef_pts = frame.to_ecef(pts_lgs)
        new_origin = ecef_pts[:n_gcp].mean(axis=0)
        if np.linalg.norm(new_origin - frame.origin_ecef_m) < 1e-7:
            break
        frame = LocalFrame.at(new_origin)
        # pixels keep their ground points' physical meaning only approximately; re-derive them
    ecef = frame.to_ecef(pts_lgs)
    geo = ecef_to_geodetic(ecef)
    points = []
    observations = []
    roles = ["gcp"] * n_gcp + ["check"] * n_check
    for k, ((l, c), role, gp) in enumerate(zip(pix, roles, geo)):
        pid = f"{'G' if role == 'gcp' else 'C'}{k:03d}"
        coords = gp.copy()
        pt: dict[str, Any] = {"id": pid, "role": role}
        if role == "gcp" and gcp_sigma_m:
            # survey noise along east/north/up, converted back to geographic
            noisy = frame.to_ecef(pts_lgs[k] + nrng.normal(0, gcp_sigma_m, 3))
            coords = ecef_to_geodetic(noisy[None, :])[0]
            pt["sigma_m"] = [gcp_sigma_m] * 3
        pt["coordinates"] = [float(x) for x in coords]
        points.append(pt)
        observations.append(
            {
                "image": img.id,
                "point": pid,
                "line": float(l + nrng.normal(0, noise_px)),
                "column": float(c + nrng.normal(0, noise_px)),
                "sigma_px": noise_px,
            }
        )
    r_err = nrng.normal(0, approx_error_m / math.sqrt(3), 3)
    v_err = nrng.normal(0, 0.05, 3)
    job = {
        "schema_version": "1.0",
        "name": f"synthetic {model}",
        "crs": "EPSG:4979",
        "cameras": [{"id": "cam", **cam, "mounting_pitch_deg": pitch_deg}],
        "images": [
            {
                "id": img.id,
                "camera": "cam",
                "model": {"name": model, "options": {k: v for k, v in mopts.items()}},
                "approx_state": {
                    "position_ecef_m": [float(x) for x in r0 + r_err],
                    "velocity_ecef_m_s": [float(x) for x in v0 + v_err],
                },
            }
        ],
        "points": points,
        "observations": observations,
        "options": {"control": control},
    }
    truth = {
        "coef": coef.tolist(),
        "model": model,
        "pixels": {p["id"]: list(pix[k]) for k, p in enumerate(points)},
        "points_lgs": {p["id"]: pts_lgs[k].tolist() for k, p in enumerate(points)},
        "frame_origin_ecef": frame.origin_ecef_m.tolist(),
    }
    return job, truth


def truth_parameters(model: str, coef: np.ndarray, options: dict | None = None) -> dict[str, float]:
    """True values of a model's parameters, in report units."""
    return {p.name: float(coef[p.index] * p.to_report) for p in get_model(model).parameters(options or {})}


def position_at_line(model: str, coef: np.ndarray, kc: np.ndarray, line: float, tau_per_line: float) -> np.ndarray:
    return platform_state(get_model(model).kind.kernel, coef, kc, line * tau_per_line)[0]


__all__ = ["single_image_job", "truth_parameters", "PRISM_NADIR", "terrain_height", "AE_M", "GM_M3_S2", "J2", "OMEGA_RAD_S"]


PRISM_FOCAL_MM = {"backward": 1999.8762715, "nadir": 1999.8630195, "forward": 2000.0645632}
PRISM_PITCH_DEG = {"backward": -23.8, "nadir": 0.0, "forward": 23.8}


def _project_true(img: SyntheticImage, cam: dict, p: np.ndarray, line_guess: float, iop: dict[str, float] | None) -> tuple[float, float]:
    """Projection with the true interior orientation (chips and IOP) of ``cam``."""
    from solver.blocks.cameras import iop_names
    from solver.geometry.sensor import camera_chip
    from solver.kernels import N_IOP, project_cam
    from solver.schema.job import Camera

    if not iop and not cam.get("chips"):
        return project_point(img, cam, p, line_guess)
    camera = Camera(id="c", **cam)
    names = iop_names(camera)
    vec = np.zeros(N_IOP)
    for k, v in (iop or {}).items():
        vec[names.index(k)] = v
    kind = get_model(img.model).kind.kernel
    col = (cam["columns"] - 1) / 2.0
    line = line_guess
    for _ in range(4):  # the chip follows the column
        chip_id, dx, dy, centre = camera_chip(camera, min(max(col, 0.0), cam["columns"] - 1.0))
        k = [c.id for c in camera.chips].index(chip_id) if camera.chips else 0
        clen = (camera.chips[k].columns if camera.chips else cam["columns"]) * cam["pixel_mm"]
        oc = np.array([line, col, 1.0, cam["focal_mm"], cam["pixel_mm"], dx, dy, centre, img.tau_per_line])
        ok, line_new, col_new, *_ = project_cam(kind, img.coef, img.kc, p, oc, vec, k, clen, False)
        if camera_chip(camera, min(max(col_new, 0.0), cam["columns"] - 1.0))[0] == chip_id:
            return float(line_new), float(col_new)
        line, col = line_new, col_new
    return float(line_new), float(col_new)


def _block_cameras(lines: int, columns: int, chips: int, line_time_s: float) -> dict[str, dict[str, Any]]:
    """The three PRISM views of :func:`block_job` (job ``cameras`` entries without ids), each
    focal plane split into ``chips`` equal contiguous chips ("1".."n") when ``chips > 1``."""
    cams = {
        name: {"focal_mm": PRISM_FOCAL_MM[name], "pixel_mm": 0.0071, "line_time_s": line_time_s, "lines": lines, "columns": columns}
        for name in PRISM_FOCAL_MM
    }
    if chips > 1:
        w = columns // chips
        for cam in cams.values():
            cam["chips"] = [
                {"id": str(k + 1), "first_column": k * w, "columns": w if k < chips - 1 else columns - k * w, "dx_mm": 0.0,
                 "dy_mm": (k * w + ((w if k < chips - 1 else columns - k * w) - 1) / 2.0 - (columns - 1) / 2.0) * 0.0071}
                for k in range(chips)
            ]
    return cams


def _triplet_states(rng: np.random.Generator, frame: LocalFrame, n_triplets: int, spacing_m: float, t_mid: float,
                    satellite: bool = False) -> list[tuple]:
    """(image id, view, r0, v0, local frame, attitude angles in it) of every image: each triplet
    has its own scene centre ``spacing_m`` further along the track, with its own local vertical.

    By default the centres lie on a straight line in the first centre's tangent plane (their
    spacing on the ground shrinks with the distance: 24.6 km instead of 30 at 3,000 km, 4.6 km at
    15,000 km, where every point fell in up to 15 images) and every scene is flown at heading
    190 deg in the flat geometry of :func:`_state_for_pass`. ``satellite``: the centres along a
    geodesic from the first one with their local headings, and each view in the satellite geometry
    (a long strip as a satellite images it)."""
    from pyproj import Geod

    geod = Geod(ellps="WGS84") if satellite else None
    lon0, lat0, _h = ecef_to_geodetic(frame.origin_ecef_m[None, :])[0]
    h = math.radians(190.0)
    vdir0 = np.array([math.sin(h), math.cos(h), 0.0])
    states = []
    for t in range(n_triplets):
        if satellite:  # the track runs back along the flight (the next triplet lies behind, at heading 190 + 180)
            lon, lat, back_az = geod.fwd(lon0, lat0, 10.0, t * spacing_m) if t else (lon0, lat0, 190.0)
            heading = float(back_az) % 360.0  # the flight's heading at this centre
        else:
            lon, lat, _ = ecef_to_geodetic(frame.to_ecef(vdir0 * (-t * spacing_m))[None, :])[0]
            heading = 190.0
        h = math.radians(heading)
        kappa0 = math.atan2(-math.cos(h), math.sin(h))
        local = LocalFrame.at(geodetic_to_ecef(np.array([[lon, lat, 450.0]]))[0])
        for name in ("backward", "nadir", "forward"):
            pitch = PRISM_PITCH_DEG[name]
            r0, v0 = _state_for_pass(local, t_mid, pitch, 692e3, heading, satellite=satellite)
            seen = incidence_deg(local, pitch) if satellite else pitch
            angles_local = (math.radians(0.01 * rng.normal()), math.radians(seen + 0.01 * rng.normal()), kappa0 + math.radians(0.1 * rng.normal()))
            states.append((f"T{t:02d}-{name}", name, r0, v0, local, angles_local))
    return states


def _global_angles(local: LocalFrame, angles_local, glob: LocalFrame):
    """Attitude angles in frame ``glob`` of a rotation given by ``angles_local`` in ``local``."""
    from solver.engine.initialize import angles_from_matrix
    from solver.kernels import rotation_and_derivatives

    m_local = rotation_and_derivatives(*angles_local)[0]
    r = local.rotation_ecef_to_lgs @ glob.rotation_ecef_to_lgs.T  # global LGS -> local LGS
    return angles_from_matrix(m_local @ r)


def _block_scene(model: str, frame: LocalFrame, states: list[tuple], cams: dict, pix: list, gcp: np.ndarray, line_time_s: float):
    """The true images and ground points of the block, with the LGS moved to the centroid of the
    control points (repeated until it stops moving: the images' coefficients depend on the
    frame): (frame, images, model options per image, points (n, 3) LGS)."""
    m = get_model(model)
    rates = (math.radians(30 / 3600), math.radians(0.05 / 3600))
    for _ in range(12):
        imgs = []
        mopts_all = []
        for iid, cname, r0, v0, local, angles_local in states:
            angles = _global_angles(local, angles_local, frame)
            mopts = {}
            for e in ANGLES:
                if m.effective_orders({})[ELEMENTS.index(e)] == HELD:
                    mopts[f"{e}_deg"] = math.degrees(angles[ANGLES.index(e)])
            mopts_all.append(mopts)
            coef = true_coefficients(model, frame, r0, v0, line_time_s, angles, rates, mopts, math.radians(PRISM_PITCH_DEG[cname]))
            imgs.append(SyntheticImage(iid, model, PRISM_PITCH_DEG[cname], coef, kepler_constants(m, frame, PRISM_PITCH_DEG[cname]), m.tau_per_line(line_time_s), r0, v0))
        pts = []
        for t in range(len(pix)):
            nadir = imgs[3 * t + 1]
            for (l, c) in pix[t]:
                pts.append(ground_point_of_pixel(nadir, cams["nadir"], l, c))
        pts_lgs = np.array(pts)
        ecef_pts = frame.to_ecef(pts_lgs)
        new_origin = ecef_pts[gcp].mean(axis=0) if gcp.any() else ecef_pts.mean(axis=0)
        if np.linalg.norm(new_origin - frame.origin_ecef_m) < 1e-7:
            break
        frame = LocalFrame.at(new_origin)
    return frame, imgs, mopts_all, pts_lgs


def _approx_state(nrng: np.random.Generator, r0, v0, approx_error_m: float, state_sigma: tuple[float, float] | None) -> dict[str, Any]:
    """An image's header state: the true one with noise (as declared when ``state_sigma``)."""
    if state_sigma is not None:  # the header state is an observation: noise as declared
        r_err = nrng.normal(0, state_sigma[0], 3)
        v_err = nrng.normal(0, state_sigma[1], 3)
    else:
        r_err = nrng.normal(0, approx_error_m / math.sqrt(3), 3)
        v_err = nrng.normal(0, 0.05, 3)
    approx: dict[str, Any] = {
        "position_ecef_m": [float(x) for x in r0 + r_err],
        "velocity_ecef_m_s": [float(x) for x in v0 + v_err],
    }
    if state_sigma is not None:
        approx["sigma_position_m"], approx["sigma_velocity_m_s"] = state_sigma
    return approx


def block_job(
    model: str = "P2",
    n_triplets: int = 1,
    n_tie: int = 40,
    n_gcp: int = 12,
    n_check: int = 8,
    noise_px: float = 0.5,
    seed: int = 0,
    gcp_sigma_m: float | None = None,
    approx_error_m: float = 20.0,
    spacing_m: float = 30000.0,
    lines: int = 16000,
    columns: int = 14496,
    state_sigma: tuple[float, float] | None = None,
    noise_seed: int | None = None,
    chips: int = 1,
    iop_truth: dict[str, dict[str, float]] | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Triplets (backward/nadir/forward) generated by ``model`` itself, with tie points.

    Each triplet covers its own scene ``spacing_m`` further along track; every tie point is seen
    in the three images of its triplet, gcp/check points likewise. Counts are per triplet.
    ``chips`` splits each focal plane into equal CCD chips (ids "1".."n", contiguous, centred);
    ``iop_truth`` {camera: {iop name: value}} makes the true cameras differ from the nominal ones
    written in the job (docs/models.md section 8), observations then come from
    :func:`solver.kernels.project_cam` with the true values.
    """
    rng = np.random.default_rng(seed)
    nrng = np.random.default_rng(seed + 7919 if noise_seed is None else noise_seed)
    centre = geodetic_to_ecef(np.array([[-51.39, -22.12, 450.0]]))[0]
    frame = LocalFrame.at(centre)
    lt = 0.00037
    cams = _block_cameras(lines, columns, chips, lt)
    states = _triplet_states(rng, frame, n_triplets, spacing_m, lt * (lines - 1) / 2.0)
    n_per = n_tie + n_gcp + n_check
    # pixels chosen in each nadir image (central 80% so that the other views see them)
    pix = []
    for t in range(n_triplets):
        ls = rng.uniform(0.1, 0.9, n_per) * (lines - 1)
        cs = rng.uniform(0.05, 0.95, n_per) * (columns - 1)
        pix.append(np.column_stack([ls, cs]))
    roles = (["tie"] * n_tie) + (["gcp"] * n_gcp) + (["check"] * n_check)
    gcp = np.array([roles[k % n_per] == "gcp" for k in range(n_triplets * n_per)])
    frame, imgs, mopts_all, pts_lgs = _block_scene(model, frame, states, cams, pix, gcp, lt)
    geo = ecef_to_geodetic(frame.to_ecef(pts_lgs))
    points = []
    observations = []
    truth_pix: dict[str, dict[str, list[float]]] = {}
    for k, p in enumerate(pts_lgs):
        t, j = divmod(k, n_per)
        role = roles[j]
        pid = f"T{t:02d}-{role[0].upper()}{j:05d}"
        pt: dict[str, Any] = {"id": pid, "role": role}
        if role != "tie":
            coords = geo[k]
            if role == "gcp" and gcp_sigma_m:
                noisy = frame.to_ecef(p + nrng.normal(0, gcp_sigma_m, 3))
                coords = ecef_to_geodetic(noisy[None, :])[0]
                pt["sigma_m"] = [gcp_sigma_m] * 3
            pt["coordinates"] = [float(x) for x in coords]
        points.append(pt)
        for img, cname in zip(imgs[3 * t : 3 * t + 3], ("backward", "nadir", "forward")):
            line, col = _project_true(img, cams[cname], p, pix[t][j][0], (iop_truth or {}).get(cname))
            if not (2 <= line <= lines - 3 and 2 <= col <= columns - 3):
                continue
            truth_pix.setdefault(pid, {})[img.id] = [line, col]
            observations.append(
                {
                    "image": img.id,
                    "point": pid,
                    "line": float(line + nrng.normal(0, noise_px)),
                    "column": float(col + nrng.normal(0, noise_px)),
                    "sigma_px": noise_px,
                }
            )
    images = []
    for img, (iid, cname, r0, v0, _local, _angles), mopts in zip(imgs, states, mopts_all):
        approx = _approx_state(nrng, r0, v0, approx_error_m, state_sigma)
        images.append({"id": iid, "camera": cname, "model": {"name": model, "options": mopts}, "approx_state": approx})
    job = {
        "schema_version": "1.0",
        "name": f"synthetic block {model} x{n_triplets}",
        "crs": "EPSG:4979",
        "cameras": [{"id": n, **cams[n], "mounting_pitch_deg": PRISM_PITCH_DEG[n]} for n in cams],
        "images": images,
        "points": points,
        "observations": observations,
        "options": {"control": "weighted"},
    }
    truth = {
        "model": model,
        "coef": {img.id: img.coef.tolist() for img in imgs},
        "points_lgs": {pt["id"]: pts_lgs[k].tolist() for k, pt in enumerate(points)},
        "pixels": truth_pix,
    }
    return job, truth


def _ground_points(img: SyntheticImage, cam: dict, lines: np.ndarray, cols: np.ndarray,
                   frames: tuple[LocalFrame, LocalFrame] | None = None) -> np.ndarray:
    """LGS points (n, 3) on the terrain seen by the pixels (lines, cols) of ``img`` with its true
    orientation: :func:`ground_point_of_pixel` with the height iterations done for all at once.

    ``frames`` = (the job's frame, the scene's own local frame): the terrain is laid on the
    scene's tangent plane instead of the job's (a long strip's far scenes would otherwise lie on
    a plane up to hundreds of km above the ellipsoid: 1,500 km from the origin, 176 km); the
    points are returned in the job's frame."""
    kind = get_model(img.model).kind.kernel
    rays = [ray(kind, img.coef, img.kc, _obs_consts(cam, line, col, 1.0, img.tau_per_line)) for line, col in zip(lines, cols)]
    s = np.array([r[0] for r in rays]).reshape(-1, 3)
    d = np.array([r[1] for r in rays]).reshape(-1, 3)
    if frames is not None:
        job_frame, scene = frames
        s = scene.to_lgs(job_frame.to_ecef(s))
        d = scene.vector_to_lgs(job_frame.vector_to_ecef(d))
    z = np.zeros(len(s))
    for _ in range(30):
        lam = (z - s[:, 2]) / d[:, 2]
        z_new = terrain_height(s[:, 0] + lam * d[:, 0], s[:, 1] + lam * d[:, 1])
        if np.max(np.abs(z_new - z), initial=0.0) < 1e-6:
            z = z_new
            break
        z = z_new
    lam = (z - s[:, 2]) / d[:, 2]
    p = s + lam[:, None] * d
    return p if frames is None else frames[0].to_lgs(frames[1].to_ecef(p))


def connected_strip_job(
    model: str = "P2",
    n_triplets: int = 100,
    points_per_triplet: int = 2200,
    n_gcp: int = 100,
    n_check: int = 100,
    noise_px: float = 0.5,
    seed: int = 0,
    spacing_m: float = 30000.0,
    state_sigma: tuple[float, float] | None = (20.0, 0.05),
    approx_error_m: float = 20.0,
    lines: int = 16000,
    columns: int = 14496,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A connected strip: ``n_triplets`` consecutive PRISM triplets (backward/nadir/forward)
    generated by ``model`` itself, whose scenes (about 40 km long) follow each other every
    ``spacing_m`` along the track, so that neighbouring scenes overlap (by a quarter at 30 km)
    and every point is observed in every image it falls in: 3 images inside one scene, 6 in an
    overlap, and the images of the whole strip are linked through shared points as in a real
    strip (the reduced camera system is banded, not block-diagonal as with :func:`block_job`).

    ``points_per_triplet`` tie points are drawn in each nadir image (lines 2-98 %, columns
    5-95 %); ``n_gcp`` control and ``n_check`` check points are spread evenly along the strip.
    Header states: weighted with ``state_sigma`` (m, m/s) and noise drawn from it, or, with
    ``state_sigma=None``, unweighted approximations ``approx_error_m`` off. The scenes follow a
    geodesic, each view as a satellite takes it (``_triplet_states(satellite=True)``: the camera
    pitched by its mounting angle off the platform's own vertical), so that a strip thousands of
    kilometres long keeps its spacing and its geometry. Returns (job, truth).
    """
    if n_gcp < 1 or n_triplets < 1:
        raise ValueError("a strip needs a triplet and a control point")
    rng = np.random.default_rng(seed)
    nrng = np.random.default_rng(seed + 7919)
    centre = geodetic_to_ecef(np.array([[-51.39, -22.12, 450.0]]))[0]
    frame = LocalFrame.at(centre)
    lt = 0.00037
    cams = _block_cameras(lines, columns, 1, lt)
    states = _triplet_states(rng, frame, n_triplets, spacing_m, lt * (lines - 1) / 2.0, satellite=True)
    # control: gcp k in triplet floor((k + 1/2) n / n_gcp), checks likewise, at random pixels
    ctrl_t = [int((k + 0.5) * n_triplets / n_gcp) for k in range(n_gcp)] + [int((k + 0.5) * n_triplets / n_check) for k in range(n_check)]
    ctrl_role = ["gcp"] * n_gcp + ["check"] * n_check
    ctrl_pix = np.column_stack([rng.uniform(0.1, 0.9, len(ctrl_t)) * (lines - 1), rng.uniform(0.05, 0.95, len(ctrl_t)) * (columns - 1)])
    pix = [ctrl_pix[[k for k, t in enumerate(ctrl_t) if t == tt]] for tt in range(n_triplets)]
    order = [k for tt in range(n_triplets) for k, t in enumerate(ctrl_t) if t == tt]  # _block_scene's order of the control points
    gcp = np.array([ctrl_role[k] == "gcp" for k in order])
    frame, imgs, mopts_all, _flat = _block_scene(model, frame, states, cams, pix, gcp, lt)
    scene_frame = [states[3 * t][4] for t in range(n_triplets)]  # each triplet's own tangent plane

    def ground(t: int, ls: np.ndarray, cs: np.ndarray) -> np.ndarray:
        return _ground_points(imgs[3 * t + 1], cams["nadir"], ls, cs, (frame, scene_frame[t]))

    ctrl_lgs = np.concatenate([ground(t, pix[t][:, 0], pix[t][:, 1]) for t in range(n_triplets) if len(pix[t])]).reshape(-1, 3)
    kind = get_model(model).kind.kernel
    scene_lines = spacing_m / (6820.0 * lt)  # lines between neighbouring scenes' centres (ground speed ~6.8 km/s)
    reach = int(math.ceil(lines / scene_lines))  # neighbours a point may fall in
    points: list[dict[str, Any]] = []
    observations: list[dict[str, Any]] = []
    truth_pts: dict[str, list[float]] = {}
    names = ("backward", "nadir", "forward")

    def observe(pid: str, p: np.ndarray, t: int, line0: float) -> None:
        for tt in range(max(0, t - reach), min(n_triplets, t + reach + 1)):
            guess = line0 + (tt - t) * scene_lines
            for v, cname in enumerate(names):
                img = imgs[3 * tt + v]
                oc = _obs_consts(cams[cname], guess, (columns - 1) / 2.0, 1.0, img.tau_per_line)
                ok, line, col, *_ = project(kind, img.coef, img.kc, p, oc, False)
                if ok and 2 <= line <= lines - 3 and 2 <= col <= columns - 3:
                    observations.append({"image": img.id, "point": pid, "line": float(line + nrng.normal(0, noise_px)),
                                         "column": float(col + nrng.normal(0, noise_px)), "sigma_px": noise_px})

    geo = ecef_to_geodetic(frame.to_ecef(ctrl_lgs)) if len(ctrl_lgs) else np.zeros((0, 3))
    counters = {"gcp": 0, "check": 0}
    for q, k in enumerate(order):
        role = ctrl_role[k]
        counters[role] += 1
        pid = f"{'G' if role == 'gcp' else 'C'}{counters[role]:04d}"
        points.append({"id": pid, "role": role, "coordinates": [float(x) for x in geo[q]]})
        truth_pts[pid] = ctrl_lgs[q].tolist()
        observe(pid, ctrl_lgs[q], ctrl_t[k], ctrl_pix[k, 0])
    for t in range(n_triplets):
        ls = rng.uniform(0.02, 0.98, points_per_triplet) * (lines - 1)
        cs = rng.uniform(0.05, 0.95, points_per_triplet) * (columns - 1)
        pts = ground(t, ls, cs)
        for j in range(points_per_triplet):
            pid = f"T{t:03d}-{j:05d}"
            points.append({"id": pid, "role": "tie"})
            truth_pts[pid] = pts[j].tolist()
            observe(pid, pts[j], t, ls[j])
    images = []
    for img, (iid, cname, r0, v0, _local, _angles), mopts in zip(imgs, states, mopts_all):
        approx = _approx_state(nrng, r0, v0, approx_error_m, state_sigma)
        images.append({"id": iid, "camera": cname, "model": {"name": model, "options": mopts}, "approx_state": approx})
    job = {
        "schema_version": "1.0",
        "name": f"connected strip {model}, {n_triplets} triplets",
        "crs": "EPSG:4979",
        "cameras": [{"id": n, **cams[n], "mounting_pitch_deg": PRISM_PITCH_DEG[n]} for n in cams],
        "images": images,
        "points": points,
        "observations": observations,
        "options": {"control": "weighted"},
    }
    truth = {"model": model, "coef": {img.id: img.coef.tolist() for img in imgs}, "points_lgs": truth_pts}
    return job, truth
