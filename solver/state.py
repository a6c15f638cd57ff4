"""The adjustment's data: images, ground points, image observations and the parameter blocks
as the solver's arrays.

Data only: built by :mod:`solver.engine.assemble` (assembly from a job; the blocks by their
kinds, :mod:`solver.blocks.registry`), filled by :mod:`solver.engine.initialize`, read by every
later stage. Frames: ground points are carried in the LGS (east, north, up at the centroid of
the control points, metres) whatever the platform model.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.geometry.geodesy import LocalFrame
from solver.platforms import PlatformModel
from solver.schema.job import Camera, Job


@dataclass
class ImageState:
    """One image in the adjustment: model, constants, and current parameter values."""

    id: str
    index: int
    camera: Camera | None  # None: a kind without camera (an RPC image, model.kind.has_camera)
    model: PlatformModel
    options: dict
    kc: np.ndarray  # (N_KEPLER_CONST,) = (18,) Kepler constants (also set, unused, for polynomial models), then a pass segment and the attitude base
    base: np.ndarray  # (24,) full coefficients (held values and current free values)
    free_idx: np.ndarray  # (nfree,) int64
    tau_per_line: float
    initial: dict = field(default_factory=dict)  # job's initial values, report units
    pass_index: int = -1  # pass-propagated models: index in Problem.passes
    platform: Any = None  # its platform block (solver.blocks.platform.PlatformBlock; shared by images sharing an attitude)

    @property
    def params(self) -> np.ndarray:
        """(nfree,) the free coefficients: its platform block's array, which Ceres moves."""
        return self.platform.params

    @property
    def kind(self) -> int:
        """The kernels' dispatch code of the model's kind (``model.kind.kernel``); the stages ask
        the kind object (``model.kind``), never this number."""
        return self.model.kind.kernel

    @property
    def nfree(self) -> int:
        return int(self.free_idx.shape[0])

    def coef(self) -> np.ndarray:
        """Current full coefficient vector."""
        c = self.base.copy()
        c[self.free_idx] = self.params
        return c


@dataclass
class PointState:
    """A ground point: known LGS coordinates (gcp/check), estimated parameter block (tie or
    weighted gcp), or both."""

    id: str
    index: int
    role: str
    known_lgs: np.ndarray | None
    sigma_m: np.ndarray | None  # survey sigmas (east, north, up) for weighted gcps
    estimated: bool  # True: a 3-parameter block in the adjustment
    xyz: np.ndarray = field(default_factory=lambda: np.zeros(3))  # current LGS (parameter block)

    @property
    def params(self) -> np.ndarray:
        """The point's parameter block: its LGS coordinates (m)."""
        return self.xyz

    @property
    def nfree(self) -> int:
        return 3 if self.estimated else 0


@dataclass
class Observations:
    """Image observations as arrays (one row each)."""

    img: np.ndarray  # (n,) image index
    pt: np.ndarray  # (n,) point index
    oc: np.ndarray  # (n, 9) observation constants (see solver.kernels)
    chip: list[str]
    source_index: np.ndarray  # (n,) index in job.observations
    cam: np.ndarray | None = None  # (n,) camera index (the camera blocks' order, solver.blocks.cameras.CameraState)
    chip_idx: np.ndarray | None = None  # (n,) chip position in the camera's chip list


@dataclass
class AdjustmentState:
    """The whole adjustment's data: the job, its local frame, the images, points and
    observations, and the parameter blocks by kind (``blocks[kind name]``, the kinds of
    :mod:`solver.blocks.registry`) with their current values (the arrays Ceres moves)."""

    job: Job
    frame: LocalFrame
    images: list[ImageState]
    points: list[PointState]
    obs: Observations
    lines: Any = None  # solver.observations.lines.LineSet: straight-line observations (None without lines)
    blocks: dict[str, list] = field(default_factory=dict)

    @property
    def cameras(self) -> list:
        """The cameras' interior-orientation blocks (solver.blocks.cameras.CameraState, one per job camera)."""
        return self.blocks.get("camera", [])

    @property
    def passes(self) -> list:
        """The passes' orbit-state blocks (solver.blocks.passes.PassState, one per pass)."""
        return self.blocks.get("pass", [])

    @property
    def adjusted_mask(self) -> np.ndarray:
        """Observations that enter the adjustment (not of check points)."""
        adjusted = np.fromiter((p.role != "check" for p in self.points), dtype=bool, count=len(self.points))
        return adjusted[self.obs.pt]


def grouped(key_of_row: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows grouped by key (0 .. n_keys - 1) by one stable sort: the rows of key k are
    ``order[bounds[k]:bounds[k + 1]]``, ascending (a mask per key would cost keys x rows)."""
    order = np.argsort(key_of_row, kind="stable")
    return order, np.searchsorted(key_of_row[order], np.arange(n_keys + 1))


def rows_by_image(img_of_row: np.ndarray, n_images: int) -> list[np.ndarray]:
    """The rows of each image (indices into ``img_of_row``, ascending): :func:`grouped`."""
    order, bounds = grouped(img_of_row, n_images)
    return [order[bounds[i] : bounds[i + 1]] for i in range(n_images)]

