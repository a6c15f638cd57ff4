"""The cameras' interior orientation as parameter blocks (kind ``camera``): each camera's full
interior-orientation vector, which parameters ``options.self_calibration`` frees (one Ceres
block per camera, shared by its images; :class:`solver.schema.settings.BlockConfig`
``self_calibration``), their prior sigmas and a reused camera's covariance; validated, counted
and reported (section ``cameras``) here. The priors (the observation family) are
:mod:`solver.observations.interior`; the parameters are named in docs/models.md section 8.

Equations in docs/models.md section 8 and :func:`solver.kernels.camera_model`. Every camera has
a full IOP vector (``N_IOP``): the optical parameters ``x0, y0, df, k1, k2, sy`` then, per chip
in the order of ``camera.chips``, ``a0, b0, a1, b1, delta`` (named ``a0@<chip id>``). Values
come from ``camera.iop`` (default 0); the master chip's parameters stay fixed; some are
weighted (seed 001: a0, b0 with 1.5 px, a1, b1 with 300 ppm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.blocks.kind import BlockDefaults
from solver.errors import Problem
from solver.kernels.layout import IOP_CHIP, IOP_OPTICAL, MAX_CHIPS, N_IOP
from solver.schema.iop_names import camera_iop_names
from solver.schema.job import Camera, Job, SelfCalibration
from solver.schema.settings import JobSettings

if TYPE_CHECKING:  # pragma: no cover
    from solver.schema.settings import BlockConfig
    from solver.state import AdjustmentState

UNITS = {"x0": "mm", "y0": "mm", "df": "mm", "k1": "mm^-2", "k2": "mm^-4", "sy": "1",
         "a0": "mm", "b0": "mm", "a1": "1", "b1": "1", "delta": "rad"}

DEFAULT_SIGMAS = {"a0": 1.5 * 0.0071, "b0": 1.5 * 0.0071, "a1": 300e-6, "b1": 300e-6}  # seed 001


def chip_ids(camera: Camera) -> list[str]:
    """The ids of the camera's chips, in order (one chip "1" for a single-chip camera)."""
    return [c.id for c in camera.chips] if camera.chips else ["1"]


def iop_names(camera: Camera) -> list[str]:
    """Names of the full IOP vector (padding slots of absent chips are unnamed)."""
    return camera_iop_names(chip_ids(camera))


def default_master_chip(camera: Camera) -> str:
    """Seed 001 fixes chip 2: the chip with id "2", else the second chip, else the only one."""
    ids = chip_ids(camera)
    if "2" in ids:
        return "2"
    return ids[1] if len(ids) > 1 else ids[0]


@dataclass
class CameraState:
    """One camera's interior orientation in the adjustment."""

    id: str
    index: int
    camera: Camera
    names: list[str]  # full vector names (len = 6 + 5 * nchips)
    base: np.ndarray  # (N_IOP,) values (held and current free)
    free_idx: np.ndarray  # (nfree,) int64 into the full vector
    params: np.ndarray  # (nfree,) the Ceres block
    sigma: np.ndarray  # (nfree,) weighted-constraint sigmas, nan = free
    master_chip: str | None
    reuse_cov: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (free positions, mean, cov)
    chip_len_mm: list[float] = field(default_factory=list)

    @property
    def nfree(self) -> int:
        return int(self.free_idx.shape[0])

    @property
    def has_iop(self) -> bool:
        return self.nfree > 0 or bool(np.any(self.base != 0.0))

    def values(self) -> np.ndarray:
        v = self.base.copy()
        v[self.free_idx] = self.params
        return v


def expand_estimate(estimate: list[str], camera: Camera, master: str | None) -> list[str]:
    """Names to estimate: optical names as such; a chip name without @ means every non-master
    chip; ``a0@3`` one chip."""
    out: list[str] = []
    ids = chip_ids(camera)
    for name in estimate:
        if name in IOP_OPTICAL:
            out.append(name)
        elif name in IOP_CHIP:
            out += [f"{name}@{cid}" for cid in ids if cid != master]
        elif "@" in name and name.split("@")[0] in IOP_CHIP and name.split("@")[1] in ids:
            out.append(name)
        else:
            raise ValueError(f"unknown interior-orientation parameter {name!r}")
    return list(dict.fromkeys(out))


_FROM_JOB: Any = object()


def build_cameras(job: Job, sc: SelfCalibration | None = _FROM_JOB) -> list[CameraState]:
    """The cameras' IOP states (every camera of the job, in order); ``sc``: which parameters are
    estimated (None: none; by default the job's ``options.self_calibration``)."""
    sc = JobSettings.of(job).blocks.self_calibration if sc is _FROM_JOB else sc
    states = []
    for i, cam in enumerate(job.cameras):
        names = iop_names(cam)
        base = np.zeros(N_IOP)
        for k, v in (cam.iop or {}).items():
            if k in names:
                base[names.index(k)] = float(v)
        estimate: list[str] = []
        master = None
        sigma_of: dict[str, float | None] = {}
        if sc is not None and (sc.cameras is None or cam.id in sc.cameras):
            master = sc.master_chip.get(cam.id) or default_master_chip(cam)
            estimate = [n for n in expand_estimate(sc.estimate, cam, master) if f"{cam.id}/{n}" not in sc.exclude]
            sigma_of = {**DEFAULT_SIGMAS, **sc.sigmas}
        free = np.array([names.index(n) for n in estimate], dtype=np.int64)
        sig = np.array([sigma_of.get(n.split("@")[0]) or math.nan for n in estimate], dtype=float)
        reuse = None
        if cam.iop_use == "weighted" and cam.iop_covariance is not None and len(free):
            cn = list(cam.iop_covariance.names)
            mat = np.array(cam.iop_covariance.matrix, dtype=float)
            pos = [q for q, n in enumerate(estimate) if n in cn]
            if pos:
                idx = [cn.index(estimate[q]) for q in pos]
                reuse = (np.array(pos), base[free[pos]].copy(), mat[np.ix_(idx, idx)])
        lens = [c.columns * (cam.pixel_mm or 0.0) for c in cam.chips] if cam.chips else [(cam.columns or 0) * (cam.pixel_mm or 0.0)]
        states.append(CameraState(cam.id, i, cam, names, base, free, base[free].copy(), sig, master, reuse, lens))
    return states


def validate_self_calibration(job: Job) -> list[tuple[str, str, tuple]]:
    """(code, message, location) of every self-calibration problem."""
    out = []
    sc = JobSettings.of(job).blocks.self_calibration
    if sc is None:
        # the kernels' IOP vector holds MAX_CHIPS chips: a camera with more chips can be used
        # without interior orientation only (its chips' offsets are in each observation's constants)
        return [("too_many_chips", f"camera {cam.id!r} has interior-orientation values (iop) and more than {MAX_CHIPS} chips",
                 ("cameras",)) for cam in job.cameras if cam.iop and len(chip_ids(cam)) > MAX_CHIPS]
    ids = {c.id for c in job.cameras}
    for cid in sc.cameras or []:
        if cid not in ids:
            out.append(("unknown_camera", f"self_calibration names unknown camera {cid!r}", ("options", "self_calibration", "cameras")))
    for cam in job.cameras:
        if len(chip_ids(cam)) > MAX_CHIPS:
            out.append(("too_many_chips", f"camera {cam.id!r} has more than {MAX_CHIPS} chips", ("cameras",)))
            continue
        master = sc.master_chip.get(cam.id)
        if master is not None and master not in chip_ids(cam):
            out.append(("unknown_chip", f"master chip {master!r} is not a chip of camera {cam.id!r}", ("options", "self_calibration", "master_chip")))
        try:
            expand_estimate(sc.estimate, cam, master or default_master_chip(cam))
        except ValueError as exc:
            out.append(("unknown_iop", str(exc), ("options", "self_calibration", "estimate")))
    for k in sc.sigmas:
        if k not in UNITS:
            out.append(("unknown_iop", f"unknown interior-orientation parameter {k!r} in sigmas", ("options", "self_calibration", "sigmas")))
    return out


def cameras_report(cameras: list[CameraState], cov_block, var_factor: float) -> list[dict[str, Any]]:
    """Report entries of the cameras with interior orientation (values, sigmas, covariance).

    ``cov_block(camera_index)`` returns the camera's free-parameter covariance (a-priori scale)
    or None. Shape follows what the service's camera library reads: ``iop`` {name: value} and
    ``iop_covariance`` {names, matrix}.
    """
    out = []
    for st in cameras:
        if not st.has_iop:
            continue
        vals = st.values()
        cov = cov_block(st.index) if st.nfree else None
        free_names = [st.names[i] for i in st.free_idx]
        params = []
        for q, name in enumerate(st.names):
            est = name in free_names
            sigma = None
            if est and cov is not None:
                sigma = float(math.sqrt(max(cov[free_names.index(name), free_names.index(name)] * var_factor, 0.0)))
            if est or vals[q] != 0.0:
                base = name.split("@")[0]
                params.append({
                    "name": name,
                    "value": float(vals[q]),
                    "sigma": sigma,
                    "unit": UNITS[base],
                    "estimated": est,
                    "significant": None if sigma is None else bool(abs(vals[q]) >= sigma),
                })
        out.append({
            "id": st.id,
            "master_chip": st.master_chip,
            "parameters": params,
            "iop": {p["name"]: p["value"] for p in params},
            "iop_covariance": None if cov is None else {"names": free_names, "matrix": (cov * var_factor).tolist()},
        })
    return out


class CameraKind(BlockDefaults):
    """The cameras' free interior orientation: one block per camera (every camera of the job,
    in order; a camera without free parameters has an empty block, not laid out). Checked and
    counted from ``options.self_calibration``; report section ``cameras``."""

    name = "camera"

    def check(self, job: Job) -> tuple[list[Problem], int]:
        issues = [Problem(code, msg, loc) for code, msg, loc in validate_self_calibration(job)]
        return issues, 0 if issues else sum(st.nfree for st in build_cameras(job))

    def build(self, problem: "AdjustmentState", config: "BlockConfig") -> list[CameraState]:
        return build_cameras(problem.job, config.self_calibration)

    def names(self, problem: "AdjustmentState") -> list[str]:
        return [f"camera:{cam.id}/{cam.names[i]}" for cam in self.blocks(problem) for i in cam.free_idx]

    def report(self, problem: "AdjustmentState", ctx: Any) -> dict[str, Any]:
        cameras = self.blocks(problem)
        return {"cameras": cameras_report(cameras, lambda ci: ctx.block(self.name, ci, cameras[ci].nfree), ctx.var_factor)}


KIND = CameraKind()
