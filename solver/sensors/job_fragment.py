"""A vendor product as a fragment of our job: a camera, an image with ephemeris, attitude samples
and line times, a default model and the options that weight them, plus how far that job form
is from the vendor's exact model (pixels).

Mapping (docs/models.md sections 1, 9, 10):

- Camera frame. Ours has ``x`` along track, ``z`` away from the scene; a detector sits at
  ``(x_c, y_c)`` and looks along ``(x_c, y_c, -f)``. Maxar's camera frame has ``z`` towards the
  ground and the detector array along ``-y``; the two differ by a half turn about ``x``
  (``P = diag(1, -1, -1)``; when the Maxar ``x`` points against the flight direction, a half
  turn about ``y`` is used instead, ``diag(-1, 1, -1)``). A straight array with
  ``DETROTANGLE = 0`` is one chip of ours: ``dx_mm = DETORIGINX``, pixel pitch, and
  ``dy_mm`` so that column C sits at ``C p - DETORIGINY``; a rotated array is approximated
  (its along-track offset ``C p sin(rot)`` is left out and counted in the difference).
- Attitude. The job's samples are roll, pitch, yaw of ``A = M R_orbit^T`` (``M`` object to
  camera, ``R_orbit`` rows: along-track, cross-track, radial), ``A = Rx(roll) Ry(pitch)
  Rz(yaw)``, mounting 0. The adjustment models neither velocity aberration nor light-travel
  time nor refraction, so each sample's rotation is the *effective* one: the rotation (Kabsch
  fit over 9 detectors across the array) that makes straight rays from the perspective centre
  meet the ground where the exact model, with every correction, puts them at the product's
  mean height. What this cannot absorb (their change across the swath and with height) is in
  ``difference_px``.
- SPOT 1-7 and Pleiades: the look angles (one model, :mod:`solver.sensors.detectors`) as
  straight chips about the swath's middle direction (:func:`look_angle_source`).
- Model: OA-J2 for Maxar's, SPOT 6/7's and Pleiades' short images, PASS-J2 for SPOT 1-5's long
  segments (it uses every ephemeris sample), with cubic attitude polynomials.
- The attitude samples are also the image's ``attitude_base``: the job's attitude is the
  delivered one (interpolated linearly in the angles, as the slerp of the exact model to far
  below a pixel) plus the cubic polynomials as a smooth correction, which the adjustment
  estimates (zero as delivered). Cubics alone cannot follow the pitch oscillation of some
  SPOT 1-4 scenes (10 microradians over 4.5 s: 1 px; the public WorldView-2 files' faster
  attitude motion 0.56-0.96 px). The samples then observe the correction through its
  polynomial terms only (:func:`solver.observations.attitude.reduced_term`): their departure
  from the base is zero, and counted sample by sample it would fit far inside its weights.
- Attitude weights. Maxar's file states the *absolute* accuracy of its attitude (the
  quaternion covariance, 0.0009-0.001 deg on the WorldView-2 products); that error is mostly
  one bias per image and angle (star-tracker alignment and the fused estimate's slow drift),
  not independent noise at 50 Hz. The fragment weights Maxar samples with that accuracy as a
  common error per image and angle (``bias_sigma_deg``) and, as the white part
  (``sigma_deg``: with the base, how far the correction's shape may go), the samples' own
  scatter about the model's cubic polynomials within each image's lines (per angle, pooled over the products, degrees-of-freedom corrected; at least
  :data:`MAXAR_ATTITUDE_WHITE_DEG`): jitter, quaternion rounding and what a cubic cannot
  follow, which is noise to the model. On the four WorldView-2 products of tests/data/vendor
  it is 2e-6 to 1.2e-5 deg per angle (6.7e-6 overall); a fixed value cannot serve both pairs
  (their scatter differs by a factor of two). Other formats keep their single (independent)
  sigma.
- Ephemeris weights: the file's position covariance (Maxar) or 5 m; velocities 0.01 m/s, or
  how far the file's velocities disagree with its positions when that is more (the screening's
  RMS Hermite residual over the interval, intervals of 10 s or more: SPOT 1-4, 0.02-0.16 m/s).
- Line times: a constant ``line_time_s = 1 / AVGLINERATE`` from the first line's time; a
  TLC table that departs from it is counted in the difference. Lines imaged backwards in time
  (Maxar ``SCANDIRECTION`` Reverse) cannot be expressed (a positive line time): refused.
- INPE records of map-grid rasters (level 2 and 4) are refused unless the measurements are
  declared raw (:func:`solver.sensors.inpe_cbers.map_grid`).
- ``difference_px`` measures this form with the file's own ephemeris (Lagrange) and the attitude
  samples slerped; the orientation the job will solve from (its platform model's orbit and
  attitude polynomials) is checked by :mod:`solver.sensors.self_check`.
- Times: seconds since 00:00 UTC of the product's first ephemeris date (``time_origin_utc``),
  shared by every product of one import so that the images of a pass share one scale.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import numpy as np

from solver.geometry.sensor import chip_index_of_column
from solver.sensors.detectors import LookAngles
from solver.sensors.dimap_spot5 import Spot5Product
from solver.sensors.dimap_v2 import DimapV2Product
from solver.sensors.errors import MetadataError
from solver.sensors.inpe_cbers import CbersProduct, map_grid, pointing_rotation
from solver.sensors.linescan import LinescanModel, matrix_to_quaternion, orbital_rows, quaternion_matrices
from solver.sensors.maxar import MaxarProduct
from solver.sensors.readers import reader_of
from solver.sensors.screening import Screening

KABSCH_DETECTORS = 9
DEFAULT_MODEL = "OA-J2"  # Maxar: images of 1-2 s
# SPOT 5 segments last tens of seconds (72 s for the public HRS one): OA-J2 propagates the
# first line's state alone and ends 8 px (80 m) off along track; the pass model uses every
# ephemeris sample (0.15 px).
LONG_STRIP_MODEL = "PASS-J2"
# Agile platforms turn during the image (WorldView-2: 0.1-0.2 deg/s in roll and pitch over a
# 1-1.5 s image, 2 km on the ground): cubic attitude polynomials, not the constants of the
# default orders (with them the adjustment is off by hundreds of metres).
DEFAULT_ORDERS = {"omega": 3, "phi": 3, "kappa": 3}
DEFAULT_SIGMA_VELOCITY_M_S = 0.01  # Maxar EPH carries no velocity covariance
# the floor of the white part of Maxar's attitude error (module doc; the samples' scatter about a
# cubic within the lines, 2e-6 to 1.2e-5 deg per angle on the four WorldView-2 products)
MAXAR_ATTITUDE_WHITE_DEG = 1e-6
MIN_ATTITUDE_SPACING_S = 0.015  # the job's attitude samples: Maxar's 50 Hz kept, a 100 Hz sampling thinned to 50 Hz
# at most this many attitude samples per image in the job (each costs a fit of the effective
# rotation, about 3.5 ms: a composition on the server stays within seconds); the public SPOT 5
# segment has 578 over 72 s
MAX_JOB_ATTITUDE_SAMPLES = 1000


def angles_xyz(a: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) radians (n, 3) with ``a = Rx(roll) Ry(pitch) Rz(yaw)`` (active)."""
    pitch = np.arcsin(np.clip(a[:, 0, 2], -1, 1))
    roll = np.arctan2(-a[:, 1, 2], a[:, 2, 2])
    yaw = np.arctan2(-a[:, 0, 1], a[:, 0, 0])
    return np.column_stack([roll, pitch, yaw])


def rotation_xyz(angles: np.ndarray) -> np.ndarray:
    """(n, 3, 3) ``Rx(roll) Ry(pitch) Rz(yaw)`` (active elementary rotations)."""
    r, p, y = angles[:, 0], angles[:, 1], angles[:, 2]
    o, z = np.ones_like(r), np.zeros_like(r)
    rx = np.stack([np.stack([o, z, z], -1), np.stack([z, np.cos(r), -np.sin(r)], -1), np.stack([z, np.sin(r), np.cos(r)], -1)], -2)
    ry = np.stack([np.stack([np.cos(p), z, np.sin(p)], -1), np.stack([z, o, z], -1), np.stack([-np.sin(p), z, np.cos(p)], -1)], -2)
    rz = np.stack([np.stack([np.cos(y), -np.sin(y), z], -1), np.stack([np.sin(y), np.cos(y), z], -1), np.stack([z, z, o], -1)], -2)
    return rx @ ry @ rz


def _kabsch(body: np.ndarray, ecef: np.ndarray) -> np.ndarray:
    """The rotation R (3, 3) minimising sum |R body_i - ecef_i|^2 (unit vectors, rows)."""
    u, _, vt = np.linalg.svd(ecef.T @ body)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def effective_rotations(model: LinescanModel, times: np.ndarray, height_m: float) -> np.ndarray:
    """(n, 3, 3) body-to-ECEF rotations at ``times`` that absorb every correction at ``height_m``
    (module docstring)."""
    cols = np.linspace(0, model.columns - 1, KABSCH_DETECTORS)
    tl, tt = model.tlc_lines, model.tlc_times_s
    rate = (tl[-1] - tl[0]) / (tt[-1] - tt[0])
    out = np.empty((times.size, 3, 3))
    body = model.look_body(cols)
    body /= np.linalg.norm(body, axis=1, keepdims=True)
    for k, t in enumerate(times):
        line = np.full(cols.size, tl[0] + (t - tt[0]) * rate)
        ground = model.image_to_ecef(line, cols, np.full(cols.size, height_m))
        s = model.position(np.array([t]))[0] + model.rotation(np.array([t]))[0] @ model.camera_offset_body_m
        d = ground - s
        out[k] = _kabsch(body, d / np.linalg.norm(d, axis=1, keepdims=True))
    return out


@dataclass
class SensorSource:
    """What the fragment needs of one product, whatever its format."""

    file: str
    satellite: str
    band: str
    model: LinescanModel
    ours_to_body: np.ndarray  # (3, 3): our camera-frame components to the model's body frame
    camera: dict[str, Any]  # our camera without its id: focal_mm, pixel_mm, line_time_s, lines, columns, chips
    mean_height_m: float  # height of the effective rotations' fit
    sigma_position_m: float | None
    sigma_attitude_rad: float | None
    attitude_white: bool = False  # sigma_attitude_rad is a common error per image and angle; the white part from the samples
    default_model: str = DEFAULT_MODEL
    warnings: list[str] = field(default_factory=list)  # samples not used, gaps: the note, standard error, the job
    notes: list[str] = field(default_factory=list)  # conversions (the velocities' frame): likewise
    velocity_rms_m_s: float | None = None  # how well the file's velocities agree with its positions


def maxar_source(p: MaxarProduct) -> SensorSource:
    """A Maxar product's camera (one chip, module docstring) and axes; a reverse-scanned product
    (its lines imaged backwards in time) is refused: the job's line time is positive."""
    m = p.model
    if m.line_time(np.array([m.lines - 1.0]))[0] < m.line_time(np.array([0.0]))[0]:
        raise MetadataError(p.file, "isd/IMD/IMAGE/SCANDIRECTION",
                            "Reverse: the lines were imaged backwards in time, and a job's camera has a positive line time, so "
                            "this product has no job form (pba check-sensor checks its exact model; pba import-rpc reads its RPC "
                            "for an RPC block)")
    t = np.array([m.line_time(np.array([m.lines / 2.0]))[0]])
    cam_to_body = quaternion_matrices(p.camera_to_body_wxyz[None, :])[0]
    x_cam_ecef = m.rotation(t)[0] @ cam_to_body @ np.array([1.0, 0, 0])
    forward = float(np.dot(x_cam_ecef, m.velocity(t)[0])) > 0
    axes = np.diag([1.0, -1.0, -1.0]) if forward else np.diag([-1.0, 1.0, -1.0])  # Maxar camera -> ours
    ox, oy = p.detector_origin_mm
    camera = {
        "focal_mm": p.principal_distance_mm, "pixel_mm": p.pixel_mm, "line_time_s": 1.0 / p.avg_line_rate_hz,
        "lines": m.lines, "columns": m.columns,
        "chips": [{"id": "1", "first_column": 0, "columns": m.columns, "dx_mm": axes[0, 0] * ox,
                   "dy_mm": -axes[1, 1] * ((m.columns - 1) / 2.0 * p.pixel_mm) + axes[1, 1] * oy}],
    }
    cov = p.position_covariance_m2
    sigma_p = float(np.sqrt(np.mean(cov[:, [0, 3, 5]].sum(axis=1) / 3.0))) if cov.shape[1] == 6 and np.all(cov[:, [0, 3, 5]] >= 0) else None
    return SensorSource(p.file, p.satellite, p.band, m, cam_to_body @ axes.T, camera,
                        p.rpc.height_off if p.rpc is not None else 0.0, sigma_p, p.attitude_sigma_rad,
                        attitude_white=p.attitude_sigma_rad is not None, **_screened(p.screening))


def _screened(screening: Screening, warnings: list[str] | None = None) -> dict[str, Any]:
    """The SensorSource fields of a reader's screening (``warnings``: the reader's own, which
    include the screening's, in place of the screening's)."""
    return {"warnings": list(screening.warnings if warnings is None else warnings), "notes": list(screening.notes),
            "velocity_rms_m_s": screening.velocity_rms_m_s}


SPOT5_PIXEL_MM = 0.0065  # HRG/HRS detector pitch: nominal; only its ratio to the focal length matters


CHIP_TOLERANCE_PX = 0.05  # straight chips follow the look-angle model to this (focal plane, px)
MAX_CHIPS = 64


def look_angle_chips(along_mm: np.ndarray, across_mm: np.ndarray, pixel_mm: float) -> list[dict[str, Any]]:
    """Our chips for detector positions in the focal plane (mm, one per column, ``across_mm``
    increasing by about ``pixel_mm`` a column): the fewest equal straight pieces (1, 2, 4, ...,
    :data:`MAX_CHIPS`) each with its own ``dx_mm`` (mean along-track position) and ``dy_mm``
    (mean offset from the piece's nominal scanline) that follow the positions within
    :data:`CHIP_TOLERANCE_PX`. A curved or rotated detector line (SPOT, Pleiades Neo) becomes
    several touching chips; each chip's ``dx_mm``/``dy_mm`` are then the self-calibration terms
    of its piece of the line."""
    n = along_mm.size
    k = 1
    while True:
        pieces = np.array_split(np.arange(n), k)
        chips, worst = [], 0.0
        for j, cols in enumerate(pieces):
            first, width = int(cols[0]), int(cols.size)
            ys = (cols - first - (width - 1) / 2.0) * pixel_mm
            dx, dy = float(np.mean(along_mm[cols])), float(np.mean(across_mm[cols] - ys))
            worst = max(worst, float(np.max(np.hypot(along_mm[cols] - dx, across_mm[cols] - ys - dy))) / pixel_mm)
            chips.append({"id": str(j + 1), "first_column": first, "columns": width, "dx_mm": dx, "dy_mm": dy})
        if worst <= CHIP_TOLERANCE_PX or 2 * k > min(MAX_CHIPS, n):
            return chips
        k *= 2


def look_angle_source(file: str, satellite: str, band: str, model: LinescanModel, look: LookAngles, line_period_s: float,
                      pixel_mm: float, default_model: str, screening: Screening, mean_height_m: float = 0.0) -> SensorSource:
    """A look-angle focal plane (:mod:`solver.sensors.detectors`, SPOT 1-7 and Pleiades) as
    straight chips of ours (:func:`look_angle_chips`). The look frame is first tilted about its
    along-track axis onto the middle detector's across-track angle (the *tilted* frame: the
    swath's centre on its z axis), so that equal pixels are equal angles across the swath: a
    SPOT 1-4 mirror at 30 degrees looks along tangents whose pitch grows by 8 % from one edge of
    the swath to the other, which equal chips cannot follow (2 px at their ends with 64 chips);
    about the swath's centre the pitch is constant to 0.1 %. Our camera sees ``(a, s c, -1)`` for
    the tilted frame's ``(a, c, 1)`` (``s`` = +-1 so that our axes are a rotation of the body's),
    turned half a turn about z when the columns run against our y; the focal length is the
    nominal pitch over the mean slope of ``s c`` in the column. The tilt becomes part of the
    attitude (a roll of the camera in the orbital frame)."""
    c = np.arange(model.columns, dtype=float)
    tilt = float(np.arctan(look.tangents(np.array([(model.columns - 1) / 2.0]))[1][0]))
    look_from_tilted = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tilt), np.sin(tilt)], [0.0, -np.sin(tilt), np.cos(tilt)]])
    d = look.look_frame(c) @ look_from_tilted  # rows: the tilted frame's components (look_from_tilted^T d)
    along, across = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
    s = -1.0 / float(np.sign(np.linalg.det(look.to_body)))
    slope = float(np.polyfit(c, s * across, 1)[0]) if model.columns > 1 else 1e-6
    turn = 1.0 if slope > 0 else -1.0  # columns running against our y: turn the camera about z
    ours_from_tilted = np.diag([turn, turn * s, -1.0])
    body_from_ours = look.to_body @ look_from_tilted @ ours_from_tilted  # ours_from_tilted is its own inverse
    focal = pixel_mm / abs(slope)
    chips = look_angle_chips(focal * turn * along, focal * turn * s * across, pixel_mm)
    camera = {"focal_mm": float(focal), "pixel_mm": pixel_mm, "line_time_s": line_period_s, "lines": model.lines,
              "columns": model.columns, "chips": chips}
    return SensorSource(file, satellite, band, model, body_from_ours, camera, mean_height_m, None, None, default_model=default_model,
                        **_screened(screening))


def spot5_source(p: Spot5Product) -> SensorSource:
    """A SPOT 1-5 product's camera (:func:`look_angle_source`; its body frame is the navigation
    frame O1, our x along its Y, the flight)."""
    return look_angle_source(p.file, p.mission, p.instrument, p.model, p.look, p.line_period_s, SPOT5_PIXEL_MM, LONG_STRIP_MODEL,
                             p.screening)


def dimap_v2_source(p: DimapV2Product) -> SensorSource:
    """A DIMAP v2 product's camera (:func:`look_angle_source`; body frame: the satellite frame)."""
    return look_angle_source(p.file, p.satellite, p.band, p.model, p.look, p.line_period_s, p.pixel_mm, DEFAULT_MODEL,
                             p.screening)


CBERS_PIXEL_MM = 0.013  # nominal: the records give no detector pitch; only its ratio to the focal length matters


def cbers_source(p: CbersProduct) -> SensorSource:
    """An INPE product's camera: our camera frame is the fitted pointing frame (x along track,
    z up, :mod:`solver.sensors.inpe_cbers`), one straight chip centred on the middle column with
    the fitted IFOV for a nominal 13 um pitch (the file's focal distance, where it has one, is
    reported in the note only). Model PASS-J2 (scenes of 9-110 s); ephemeris and attitude
    weights: the documented defaults (the records state none)."""
    m = p.model
    focal = CBERS_PIXEL_MM / p.ifov_rad
    camera = {
        "focal_mm": float(focal), "pixel_mm": CBERS_PIXEL_MM, "line_time_s": p.line_period_s, "lines": m.lines,
        "columns": m.columns,
        "chips": [{"id": "1", "first_column": 0, "columns": m.columns, "dx_mm": 0.0,
                   "dy_mm": float(((m.columns - 1) / 2.0 - p.centre_column) * CBERS_PIXEL_MM)}],
    }
    name = f"{p.satellite} {p.instrument}" + (f" {p.camera}" if p.camera else "")
    why = map_grid(p)
    if why is not None:
        raise MetadataError(p.file, "prdf/image/projectionName",
                            f"{why}. A rigorous job needs measurements in the raw image: name the file FILE#raw (or "
                            "FILE#left,raw) if yours are; pba check-sensor checks the record's geometry either way")
    reader = [w for w in p.warnings if w not in p.screening.notes]
    return SensorSource(p.file, name, p.instrument, m, pointing_rotation(p), camera, 0.0, None, None,
                        default_model=LONG_STRIP_MODEL, **_screened(p.screening, reader))


def _time_origin(sources: list[SensorSource]) -> datetime:
    first = min(datetime.fromisoformat(s.model.epoch_utc.replace("Z", "+00:00")) for s in sources)
    return datetime(first.year, first.month, first.day, tzinfo=timezone.utc)


DEFAULT_SIGMA_POSITION_M = 5.0  # when the file states none
DEFAULT_SIGMA_ATTITUDE_DEG = 0.002


def source(p: Any) -> SensorSource:
    """What the fragment needs of a product of any registered format (its reader's ``source``,
    :mod:`solver.sensors.readers`), or a SensorSource as it is."""
    if isinstance(p, SensorSource):
        return p
    return reader_of(p).source_of(p)


def fragment(
    products: list[MaxarProduct | Spot5Product | DimapV2Product | CbersProduct | SensorSource], image_ids: list[str]
) -> dict[str, Any]:
    """The job fragment of one or more products (``cameras``, ``images``, ``options``) and a
    ``sensor_metadata`` block per image (what was read, the job form's difference, the reader's
    warnings)."""
    sources = [source(p) for p in products]
    origin = _time_origin(sources)
    cameras, images, notes = [], [], []
    scatter_sq, scatter_dof = np.zeros(3), 0  # the samples about a cubic within the lines (white part)
    for src, image_id in zip(sources, image_ids):
        m = src.model
        shift = (datetime.fromisoformat(m.epoch_utc.replace("Z", "+00:00")) - origin).total_seconds()
        camera = {"id": image_id, **src.camera}
        t0 = float(m.line_time(np.array([0.0]))[0])
        t1 = float(m.line_time(np.array([m.lines - 1.0]))[0])
        lo, hi = min(t0, t1), max(t0, t1)
        de = float(np.median(np.diff(m.ephemeris_times_s)))
        ke = (m.ephemeris_times_s >= lo - max(0.2, 2 * de)) & (m.ephemeris_times_s <= hi + max(0.2, 2 * de))
        da = float(np.median(np.diff(m.attitude_times_s)))
        ka = (m.attitude_times_s >= lo - max(0.1, da)) & (m.attitude_times_s <= hi + max(0.1, da))
        at = m.attitude_times_s[ka]
        if da < MIN_ATTITUDE_SPACING_S:  # densely sampled polynomials (Pleiades): every k-th sample, ends kept
            step = int(np.ceil(MIN_ATTITUDE_SPACING_S / da))
            at = np.unique(np.concatenate([at[::step], at[-1:]]))
        if at.size > MAX_JOB_ATTITUDE_SAMPLES:  # a long strip: evenly spread samples, ends kept
            at = at[np.unique(np.round(np.linspace(0, at.size - 1, MAX_JOB_ATTITUDE_SAMPLES)).astype(int))]
        rot = effective_rotations(m, at, src.mean_height_m)  # body to ECEF
        ecef_to_ours = np.einsum("ij,njk->nik", src.ours_to_body.T, np.transpose(rot, (0, 2, 1)))
        a = ecef_to_ours @ np.transpose(orbital_rows(m.position(at), m.velocity(at)), (0, 2, 1))
        ang = np.degrees(np.unwrap(angles_xyz(a), axis=0))  # yaw near 180 deg stays continuous
        image = {
            "id": image_id, "camera": image_id, "model": {"name": src.default_model, "options": {"orders": dict(DEFAULT_ORDERS)}},
            "first_line_time_s": t0 + shift,
            "ephemeris": [{"time_s": float(t + shift), "position_ecef_m": [float(v) for v in pos],
                           "velocity_ecef_m_s": [float(v) for v in vel]}
                          for t, pos, vel in zip(m.ephemeris_times_s[ke], m.positions_ecef_m[ke], m.velocities_ecef_m_s[ke])],
            "attitude": [{"time_s": float(t + shift), "roll_deg": float(r[0]), "pitch_deg": float(r[1]), "yaw_deg": float(r[2])}
                         for t, r in zip(at, ang)],
        }
        image["attitude_base"] = [dict(s) for s in image["attitude"]]  # the polynomials correct the delivered attitude (module doc)
        within = (at >= lo) & (at <= hi)
        if within.sum() > 8:
            tc = at[within] - at[within].mean()
            v = np.vander(tc, 4)
            fit = ang[within] - v @ np.linalg.lstsq(v, ang[within], rcond=None)[0]
            scatter_sq += np.sum(fit**2, axis=0)
            scatter_dof += int(within.sum()) - 4
        image["sensor"] = {"file": src.file, "satellite": src.satellite, "notes": src.notes + src.warnings}
        cameras.append(camera)
        images.append(image)
        notes.append({"image": image_id, "file": src.file, "satellite": src.satellite, "band": src.band,
                      "first_line_utc": _utc(origin, t0 + shift), "time_origin_utc": origin.isoformat().replace("+00:00", "Z"),
                      "difference_px": job_form_difference(src, camera, image, shift),
                      **({"notes": src.notes} if src.notes else {}), **({"warnings": src.warnings} if src.warnings else {})})
    sig_p = [s.sigma_position_m for s in sources if s.sigma_position_m is not None]
    sig_a = [s.sigma_attitude_rad for s in sources if s.sigma_attitude_rad is not None]
    absolute = max(float(np.degrees(max(sig_a))), 1e-5) if sig_a else DEFAULT_SIGMA_ATTITUDE_DEG
    attitude: dict[str, Any] = {"sigma_deg": [absolute] * 3}
    if all(s.attitude_white for s in sources) and scatter_dof > 0:  # a common error and the samples' white part (Maxar)
        white = np.maximum(np.sqrt(scatter_sq / scatter_dof), MAXAR_ATTITUDE_WHITE_DEG)
        attitude = {"sigma_deg": [float(x) for x in white], "bias_sigma_deg": [absolute] * 3}
    # velocities that agree with their positions worse than the default weight says (SPOT 1-4:
    # 0.03-0.16 m/s) are weighted by that agreement
    sig_v = [s.velocity_rms_m_s for s in sources if s.velocity_rms_m_s is not None]
    options: dict[str, Any] = {
        "ephemeris": {"sigma_position_m": max(max(sig_p), 0.01) if sig_p else DEFAULT_SIGMA_POSITION_M,
                      "sigma_velocity_m_s": max([DEFAULT_SIGMA_VELOCITY_M_S, *sig_v])},
        "attitude": attitude,
    }
    return {"cameras": cameras, "images": images, "options": options, "sensor_metadata": notes}


def _utc(origin: datetime, seconds: float) -> str:
    return datetime.fromtimestamp(origin.timestamp() + seconds, timezone.utc).isoformat().replace("+00:00", "Z")


def job_form_difference(src: SensorSource, camera: dict[str, Any], image: dict[str, Any], shift: float,
                        n: int = 7, k: int = 3) -> dict[str, float]:
    """How far the job form (our chips, constant line rate, the effective attitude
    samples slerped, straight rays, no corrections) is from the exact model with every
    correction: RMS and maximum px over ``n`` x ``n`` image positions times ``k`` heights (the
    RPC's height range, else 0 +- 500 m)."""
    m = src.model
    chips = camera["chips"]
    f, pix = camera["focal_mm"], camera["pixel_mm"]
    first = np.array([ch["first_column"] for ch in chips], float)
    width = np.array([ch["columns"] for ch in chips], float)
    dx = np.array([ch["dx_mm"] for ch in chips])
    dy = np.array([ch["dy_mm"] for ch in chips])
    ours_to_body = src.ours_to_body

    def look_body(c: np.ndarray) -> np.ndarray:
        c = np.asarray(c, float)
        k = chip_index_of_column(list(first), [int(w) for w in width], c)
        k = np.where(k < 0, np.where(c < first.min(), int(np.argmin(first)), int(np.argmax(first))), k)  # beyond the ends
        v = np.column_stack([dx[k], (c - first[k] - (width[k] - 1) / 2.0) * pix + dy[k], np.full(c.shape, -f)])
        return v @ ours_to_body.T

    at = np.array([s["time_s"] - shift for s in image["attitude"]])
    ang = np.radians([[s["roll_deg"], s["pitch_deg"], s["yaw_deg"]] for s in image["attitude"]])
    r_orbit = orbital_rows(m.position(at), m.velocity(at))
    ecef_to_ours = rotation_xyz(ang) @ r_orbit
    body_to_ecef = np.transpose(ecef_to_ours, (0, 2, 1)) @ ours_to_body.T  # ecef_to_ours = B^T R^T
    t0 = image["first_line_time_s"] - shift
    job = LinescanModel(
        lines=m.lines, columns=m.columns, epoch_utc=m.epoch_utc,
        tlc_lines=np.array([0.0, 1.0]), tlc_times_s=np.array([t0, t0 + camera["line_time_s"]]),
        ephemeris_times_s=m.ephemeris_times_s, positions_ecef_m=m.positions_ecef_m, velocities_ecef_m_s=m.velocities_ecef_m_s,
        attitude_times_s=at, attitude_wxyz=matrix_to_quaternion(body_to_ecef), look_body=look_body,
        camera_offset_body_m=m.camera_offset_body_m,
    ).with_corrections(aberration=False, light_time=False, refraction=False)
    heights = src.mean_height_m + np.linspace(-500, 500, k)
    L, C, H = (a.ravel() for a in np.meshgrid(np.linspace(0, m.lines - 1, n), np.linspace(0, m.columns - 1, n), heights, indexing="ij"))
    g = job.image_to_ground(L, C, H)
    d = m.ground_to_image(g) - np.column_stack([L, C])
    dist = np.hypot(d[:, 0], d[:, 1])
    return {"rms": float(np.sqrt(np.nanmean(dist**2))), "max": float(np.nanmax(dist))}
