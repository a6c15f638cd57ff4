"""The cameras of a problem as parameter blocks: each camera's full interior-orientation vector,
which parameters ``options.self_calibration`` frees (one Ceres block per camera, shared by its
images), their prior sigmas and a reused camera's covariance. The priors, validation and
report of interior orientation (the observation family) are :mod:`solver.observations.interior`;
the parameters are named in docs/models.md section 8.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from solver.kernels.layout import IOP_CHIP, IOP_OPTICAL, N_IOP
from solver.schema.iop_names import camera_iop_names
from solver.schema.job import Camera, Job

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


def build_cameras(job: Job) -> list[CameraState]:
    """The cameras' IOP states (every camera of the job, in order)."""
    sc = job.options.self_calibration
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
