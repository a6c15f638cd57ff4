"""Interior-orientation errors of a simulated camera (docs/models.md section 8, seed 001 section 4).

The simulated camera may differ from the nominal camera written in the job by known interior
orientation parameters (IOP). Names and units are those of the job's ``camera.iop`` (the
contract between the solver and the simulator): per camera ``x0``, ``y0`` (mm, principal point
correction), ``df`` (mm, focal length change), ``k1`` (mm^-2), ``k2`` (mm^-4) (symmetric radial
distortion), ``sy`` (scale of y); per CCD chip ``k`` (names ``a0@<chip id>`` ...): ``a0``, ``b0``
(mm, chip shifts in x and y), ``a1`` (scale/rotation term in y), ``b1`` (rotation term in x),
``delta`` (rad, central angle of the chip's bending). Missing names are zero.

Forward equations, written here independently of the solver. For a pixel at scanline
coordinate ``y_s = (C - first_k - (n_k - 1)/2) PS`` of chip k (length ``L_k = n_k PS``)::

    x_m = dx_k + a0_k + b1_k y_s + delta_k y_s^2 / (2 L_k)
    y_m = y_s + dy_k + b0_k + (a1_k + sy) y_s
    xb  = x_m - x0,   yb = y_m - y0,   r^2 = xb^2 + yb^2        (nominal principal point 0, 0)
    x_i = xb (1 - k1 r^2 - k2 r^4),   y_i = yb (1 - k1 r^2 - k2 r^4)

and the pixel sees along the camera-frame direction ``(x_i, y_i, -(f + df))``, i.e. a ground
point with camera coordinates (X, Y, Z) images where ``x_i = -(f + df) X / Z`` and
``y_i = -(f + df) Y / Z``. With every IOP at zero this is the nominal camera
(:mod:`solver.simulate.camera`). The ground-to-image direction solves both conditions for the
acquisition time and ``y_s`` together (:mod:`solver.simulate.projection`).

Presets (``pba simulate ... --iop-errors default``): :func:`default_iop` gives each PRISM view a
focal length change of about 2 mm, chip shifts a0/b0 of 0.02-0.03 mm on the three non-master
chips (chip 2 is the master, as in seed 001) and a few ppm of a1/b1; the optical terms x0, y0,
k1, k2, sy and the bending are zero (so a significance analysis should drop them). Other cameras
get df = 1e-3 f and, if they have several chips, the same chip pattern.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

OPTICAL = ("x0", "y0", "df", "k1", "k2", "sy")
PER_CHIP = ("a0", "b0", "a1", "b1", "delta")
MASTER_CHIP = "2"

# (a0, b0, a1, b1) of chips 1, 3, 4 (mm, mm, -, -) and df (mm) per PRISM view; chip 2 is the master.
_PRISM_DEFAULTS: dict[str, dict[str, Any]] = {
    "backward": {"df": 2.0, "chips": {"1": (-0.03, 0.03, 4e-6, -3e-6), "3": (0.02, -0.03, -3e-6, 2e-6), "4": (0.03, 0.02, 2e-6, 4e-6)}},
    "nadir": {"df": 2.4, "chips": {"1": (0.03, -0.02, -2e-6, 3e-6), "3": (-0.02, 0.03, 3e-6, -4e-6), "4": (0.02, 0.03, -4e-6, -2e-6)}},
    "forward": {"df": 1.7, "chips": {"1": (0.02, 0.03, 3e-6, 2e-6), "3": (0.03, -0.03, -2e-6, -3e-6), "4": (-0.03, 0.02, 4e-6, 3e-6)}},
}


def parameter_names(chip_ids: list[str] | tuple[str, ...]) -> list[str]:
    """Every IOP name of a camera with these chips, camera terms first."""
    return list(OPTICAL) + [f"{p}@{c}" for c in chip_ids for p in PER_CHIP]


@dataclass(frozen=True)
class CameraIOP:
    """True interior-orientation errors of one simulated camera (name -> value, missing = 0)."""

    items: tuple[tuple[str, float], ...] = ()

    @classmethod
    def from_dict(cls, values: Mapping[str, float] | None) -> "CameraIOP":
        values = values or {}
        for name in values:
            base, _, chip = name.partition("@")
            if (chip and base not in PER_CHIP) or (not chip and base not in OPTICAL):
                raise ValueError(f"unknown interior orientation parameter {name!r}")
        return cls(tuple(sorted((k, float(v)) for k, v in values.items() if float(v) != 0.0)))

    def as_dict(self) -> dict[str, float]:
        return dict(self.items)

    @property
    def is_zero(self) -> bool:
        return not self.items

    def value(self, name: str, chip_id: str | None = None) -> float:
        key = f"{name}@{chip_id}" if chip_id is not None else name
        return self.as_dict().get(key, 0.0)

    def full(self, chip_ids: list[str] | tuple[str, ...]) -> dict[str, float]:
        """Every parameter of a camera with these chips, zeros included (the truth file)."""
        d = self.as_dict()
        return {n: d.get(n, 0.0) for n in parameter_names(chip_ids)}

    def image_point(
        self,
        y_s_mm: np.ndarray,
        dx_mm: np.ndarray,
        dy_mm: np.ndarray,
        chip_ids: np.ndarray,
        chip_length_mm: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distortion-corrected focal-plane coordinates (x_i, y_i) in mm of pixels at scanline
        coordinate ``y_s_mm`` on the given chips (arrays of equal length; see module doc)."""
        d = self.as_dict()
        chip_ids = np.asarray(chip_ids)

        def per_chip(p: str) -> np.ndarray:
            return np.array([d.get(f"{p}@{c}", 0.0) for c in chip_ids], dtype=float)

        y_s = np.asarray(y_s_mm, dtype=float)
        x_m = dx_mm + per_chip("a0") + per_chip("b1") * y_s + per_chip("delta") * y_s**2 / (2.0 * chip_length_mm)
        y_m = y_s + dy_mm + per_chip("b0") + (per_chip("a1") + d.get("sy", 0.0)) * y_s
        xb = x_m - d.get("x0", 0.0)
        yb = y_m - d.get("y0", 0.0)
        r2 = xb**2 + yb**2
        scale = 1.0 - d.get("k1", 0.0) * r2 - d.get("k2", 0.0) * r2**2
        return xb * scale, yb * scale


NO_IOP = CameraIOP()


def default_iop(camera_id: str, focal_mm: float, chip_ids: list[str] | tuple[str, ...]) -> CameraIOP:
    """The ``--iop-errors default`` values of a camera (see module doc)."""
    view = next((v for v in _PRISM_DEFAULTS if camera_id.endswith(v)), None)
    spec = _PRISM_DEFAULTS[view] if view is not None else {"df": 1e-3 * focal_mm, "chips": _PRISM_DEFAULTS["backward"]["chips"]}
    values: dict[str, float] = {"df": spec["df"]}
    if len(chip_ids) > 1:
        for chip, (a0, b0, a1, b1) in spec["chips"].items():
            if chip in chip_ids and chip != MASTER_CHIP:
                values |= {f"a0@{chip}": a0, f"b0@{chip}": b0, f"a1@{chip}": a1, f"b1@{chip}": b1}
    return CameraIOP.from_dict(values)


def resolve_iop(spec: Any, camera_id: str, focal_mm: float, chip_ids: list[str] | tuple[str, ...]) -> CameraIOP:
    """The IOP errors of a camera from a simulation setting: ``"none"``, ``"default"``, or a
    mapping camera id -> {name: value} (cameras not listed have none)."""
    if spec is None or spec == "none":
        return NO_IOP
    if spec == "default":
        return default_iop(camera_id, focal_mm, chip_ids)
    if isinstance(spec, Mapping):
        return CameraIOP.from_dict(spec.get(camera_id))
    raise ValueError(f"iop errors must be 'none', 'default' or a mapping camera id -> values, not {spec!r}")
