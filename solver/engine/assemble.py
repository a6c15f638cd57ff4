"""From a validated job document to the solver's arrays (the one place where conversion happens).

Frames: ground points are carried in the LGS (east, north, up at the centroid of the control
points, metres) whatever the platform model; an ECEF model rotates its Earth-fixed position
into the LGS inside the kernel (:mod:`solver.kernels`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from solver.blocks import registry as blocks
from solver.blocks.platform import attach_attitude_base, kepler_constants, platform_constants  # noqa: F401 (kepler_constants: the tests' scenes use it)
from solver.geometry.geodesy import A_WGS84_M, LocalFrame, to_ecef
from solver.geometry.sensor import chip_indices, chip_of_index
from solver.kernels import N_COEF, N_OBS_CONST
from solver.observations.line_data import build_lines, control_line_points_ecef, lines_ecef
from solver.platforms import get_model
from solver.schema.job import Job
from solver.schema.settings import BlockConfig, JobSettings
from solver.state import AdjustmentState, ImageState, Observations, PointState

RPC_CHIP = "1"  # chip name of RPC image observations (one image, no chips)


def _footprints_ecef(job: Job) -> list[np.ndarray]:
    """Where the images look, for a job without any known point (direct georeferencing with tie
    points only): an RPC's ground offset, else the sub-satellite point of the mean ephemeris or
    approximate position (on the ellipsoid)."""
    out = []
    for im in job.images:
        if im.rpc is not None:
            out.append(to_ecef([[im.rpc.long_off, im.rpc.lat_off, im.rpc.height_off]], "EPSG:4326")[0])
            continue
        pos = [s.position_ecef_m for s in im.ephemeris] or ([im.approx_state.position_ecef_m] if im.approx_state else [])
        if pos:
            p = np.mean(np.array(pos, float), axis=0)
            r = float(np.linalg.norm(p))
            if r > 0:
                out.append(p / r * A_WGS84_M)
    return out


def control_frame(job: Job, points_ecef: dict[str, np.ndarray], line_points_ecef: np.ndarray | None = None) -> LocalFrame:
    """LGS at the centroid of the control: control points and the control lines' two points each
    (without any control, of all known points; without any known point, of where the images
    look)."""
    gcps = [points_ecef[p.id] for p in job.points if p.role == "gcp"]
    if line_points_ecef is not None and len(line_points_ecef):
        gcps += list(line_points_ecef)
    if not gcps:
        gcps = list(points_ecef.values())
    if not gcps:
        gcps = _footprints_ecef(job)
    return LocalFrame.at_centroid(np.array(gcps))


def ground_points_ecef(job: Job) -> dict[str, np.ndarray]:
    """ECEF coordinates of every point that has coordinates, converted per CRS in batches."""
    by_crs: dict[str, list] = {}
    for p in job.points:
        if p.coordinates is not None:
            by_crs.setdefault(p.crs or job.crs, []).append(p)
    out: dict[str, np.ndarray] = {}
    for crs, pts in by_crs.items():
        xyz = to_ecef(np.array([p.coordinates for p in pts], dtype=float), crs)
        for p, e in zip(pts, xyz):
            out[p.id] = e
    return out


def _chip_indices(job: Job, images: list, obs_img: np.ndarray) -> np.ndarray:
    """Chip index (in its camera's chips) of every observation, computed per camera in one
    vectorised pass (validation guarantees every column is on a chip; RPC images: 0)."""
    observations = job.observations
    out = np.zeros(len(observations), dtype=np.int64)
    if not len(observations):
        return out
    columns = np.fromiter((o.column for o in observations), dtype=float, count=len(observations))
    by_camera: dict[str, list[int]] = {}  # camera id (unique in a valid job) -> its images
    cams: dict[str, Any] = {}
    for im in images:
        if im.camera is not None:
            by_camera.setdefault(im.camera.id, []).append(im.index)
            cams[im.camera.id] = im.camera
    for key, image_indices in by_camera.items():
        ks = np.flatnonzero(np.isin(obs_img, image_indices))
        out[ks] = chip_indices(cams[key], columns[ks], [observations[k].chip for k in ks.tolist()])
    return out


def _image_chip_table(images: list) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Per image: the first row of its chips in one table; per chip row: dx - x0, dy - y0 (mm),
    centre column, and its id (RPC images: one row of zeros, chip :data:`RPC_CHIP`)."""
    first = np.zeros(len(images), dtype=np.int64)
    rows: list[tuple[float, float, float]] = []
    ids: list[str] = []
    for im in images:
        first[im.index] = len(rows)
        cam = im.camera
        if cam is None:
            rows.append((0.0, 0.0, 0.0))
            ids.append(RPC_CHIP)
            continue
        x0, y0 = cam.principal_point_mm
        for k in range(max(len(cam.chips), 1)):
            chip_id, dx, dy, centre = chip_of_index(cam, k)
            rows.append((dx - x0, dy - y0, centre))
            ids.append(chip_id)
    return first, np.array(rows, dtype=float).reshape(-1, 3), ids


def _observation_constants(observations: list, images: list, obs_img: np.ndarray, chip_of_obs: np.ndarray) -> np.ndarray:
    """The observation constants ``oc`` (:mod:`solver.kernels`) of every observation, in array
    passes: measured line, column, sigma (px), then the camera's focal length and pixel size
    (mm), the chip's offset from the principal point (mm), its centre column and the model's
    tau per line (RPC images: zeros after the sigma)."""
    n = len(observations)
    oc = np.zeros((n, N_OBS_CONST))
    if n == 0:
        return oc
    oc[:, 0] = np.fromiter((o.line for o in observations), dtype=float, count=n)
    oc[:, 1] = np.fromiter((o.column for o in observations), dtype=float, count=n)
    oc[:, 2] = np.fromiter((o.sigma_px for o in observations), dtype=float, count=n)
    per_image = np.array(
        [(im.camera.focal_mm, im.camera.pixel_mm, im.tau_per_line) if im.camera is not None else (0.0, 0.0, 0.0) for im in images],
        dtype=float,
    ).reshape(-1, 3)
    first, chip_rows, _ids = _image_chip_table(images)
    chip_row = first[obs_img] + chip_of_obs
    oc[:, 3] = per_image[obs_img, 0]
    oc[:, 4] = per_image[obs_img, 1]
    oc[:, 5:8] = chip_rows[chip_row]
    oc[:, 8] = per_image[obs_img, 2]
    return oc


def _chip_ids(images: list, obs_img: np.ndarray, chip_of_obs: np.ndarray) -> list[str]:
    """The chip id of every observation (RPC images: :data:`RPC_CHIP`)."""
    first, _rows, ids = _image_chip_table(images)
    return [ids[r] for r in (first[obs_img] + chip_of_obs).tolist()]


def build_problem(job: Job, models: dict[str, str] | None = None, config: BlockConfig | None = None) -> AdjustmentState:
    """Assemble arrays from a job that passed :func:`solver.engine.validate.validate_job`: the
    images, points and observations, then the parameter blocks of every kind
    (:mod:`solver.blocks.registry`; ``config``: which are estimated, default from the job's options).

    Parameter values are zero here; :mod:`solver.engine.initialize` fills them.
    """
    cameras = {c.id: c for c in job.cameras}
    ecef = ground_points_ecef(job)
    line_ecef = lines_ecef(job) if job.lines else {}
    frame = control_frame(job, ecef, control_line_points_ecef(job, line_ecef))
    config = config if config is not None else JobSettings.of(job).blocks
    weighted = config.control == "weighted"  # a control point with a survey sigma is a block of its own

    images: list[ImageState] = []
    for i, im in enumerate(job.images):
        model = get_model((models or {}).get(im.id, im.model.name))
        opts = dict(im.model.options)
        free = model.free_indices(opts)
        cam, kc, tau_per_line = platform_constants(model, im, frame, cameras)
        images.append(
            ImageState(
                id=im.id,
                index=i,
                camera=cam,
                model=model,
                options=opts,
                kc=kc,
                base=np.zeros(N_COEF),
                free_idx=free,
                tau_per_line=tau_per_line,
                initial=dict(im.initial),
            )
        )

    points: list[PointState] = []
    for j, p in enumerate(job.points):
        known = frame.to_lgs(ecef[p.id]) if p.id in ecef else None
        sigma = np.array(p.sigma_m, dtype=float) if p.sigma_m is not None else None
        estimated = p.role == "tie" or (p.role == "gcp" and weighted and sigma is not None)
        pt = PointState(p.id, j, p.role, known, sigma, estimated)
        if known is not None:
            pt.xyz = known.copy()
        points.append(pt)

    img_index = {im.id: im.index for im in images}
    pt_index = {p.id: p.index for p in points}
    observations = job.observations
    n = len(observations)
    obs_img = np.fromiter((img_index[o.image] for o in observations), dtype=np.int64, count=n)
    obs_pt = np.fromiter((pt_index[o.point] for o in observations), dtype=np.int64, count=n)
    chip_of_obs = _chip_indices(job, images, obs_img)
    oc = _observation_constants(observations, images, obs_img, chip_of_obs)
    chips = _chip_ids(images, obs_img, chip_of_obs)
    cam_index = {c.id: k for k, c in enumerate(job.cameras)}
    # RPC images have no camera: index -1 (the kernels never read a camera for them)
    cam_of_image = np.array([cam_index[im.camera.id] if im.camera else -1 for im in images], dtype=np.int64)
    obs_cam = cam_of_image[obs_img] if n else np.zeros(0, dtype=np.int64)
    obs_chip = chip_of_obs  # the index in chip_ids(camera) (chip ids are unique; RPC images: 0)
    obs = Observations(obs_img, obs_pt, oc, chips, np.arange(n), obs_cam, obs_chip)
    lines = build_lines(job, frame, images, line_ecef) if job.lines else None
    problem = AdjustmentState(job, frame, images, points, obs, lines)
    blocks.build(problem, config)
    attach_attitude_base(problem)  # after the blocks: the pass kind builds its images' kc anew
    return problem


def parameter_names(problem: AdjustmentState) -> list[str]:
    """Names of the columns before the points, in layout order ("image/param", "camera:id/iop",
    "pass:id/X", ...: each block kind's :meth:`~solver.blocks.kind.BlockKind.names`)."""
    return blocks.names(problem)
