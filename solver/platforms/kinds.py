"""Platform kinds: what a family of platform models is, in the one place the stages ask it.

A platform *model* (:class:`solver.platforms.registry.PlatformModel`) is a kind plus its orders,
held angles and options. The *kind* says how the model's parameters become a perspective centre
and a rotation, and everything the stages outside the kernels need to know about that:

* ``kernel``: the dispatch code of its numerical kernel (``KIND_*``, :mod:`solver.kernels.layout`);
  the kernels are the only code that branches on it;
* ``has_camera``: False for a kind whose sensor model is the image's RPC (no camera, no
  platform, an image-space bias; its priors are ``bias_prior``);
* ``earth_fixed``: the position comes from an Earth-fixed orbit state and the time variable is in
  seconds (``t = L * line_time``), else the time is the line number (tau = L / 1000);
* ``ecef_state``: the image's own coefficients hold the ECEF state (S0 at line 0, velocity u),
  so its initial values and state priors are ECEF vectors; else they are LGS polynomial
  coefficients (or nothing, for a pass or an RPC);
* ``shares_pass_orbit``: the orbit state is one block shared by the images of a pass (its
  initial values, priors and ephemeris observations are the pass's, :mod:`solver.observations.passes`);
* ``attitude_in_orbital_frame``: the angles are roll, pitch, yaw relative to the orbital frame
  (measured attitude attaches to it; no levelling, resection gives zero);
* ``parameters`` (names, units, scales in the report), ``tau_per_line`` (its time scale) and
  ``attitude_time_offset`` (where its angle polynomials start).

Adding a kind: a subclass (or an instance) of :class:`PlatformKind` in its model module, its
kernel branch (a new ``KIND_*`` code and its evaluation in :mod:`solver.kernels.platform`, or an
existing code when it shares that mathematics), and one ``register_kind`` line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from solver.kernels.layout import KIND_KEPLER, KIND_ORBIT_ATTITUDE, KIND_PASS, KIND_POLYNOMIAL, KIND_RPC, PASS_ATT_OFF

ELEMENTS = ("X", "Y", "Z", "omega", "phi", "kappa")
ANGLES = ("omega", "phi", "kappa")
POLY_TIME_SCALE_LINES = 1000.0  # tau = L / 1000 for polynomial models (conditioning)
_DEG = 180.0 / math.pi


def coef_index(element: str, power: int) -> int:
    """Index of coefficient (element, power) in the flattened full vector."""
    return ELEMENTS.index(element) * 4 + power


class PlatformModel(Protocol):
    """What a kind reads of its model (:class:`solver.platforms.registry.PlatformModel`; the
    registry imports this module, not the other way round)."""

    angle_names: tuple[str, str, str]
    bias: tuple[tuple[str, str, int], ...]


@dataclass(frozen=True)
class ParameterSpec:
    """One estimated parameter: its name, report unit and place in the full vector.

    ``to_report`` multiplies the internal value (m or rad per tau^k) to give the report value.
    """

    name: str
    unit: str
    index: int
    to_report: float


@dataclass(frozen=True)
class PlatformKind:
    """A kind of platform model; see the module docstring for what each field answers."""

    name: str
    kernel: int
    has_camera: bool = True
    earth_fixed: bool = False
    ecef_state: bool = False
    shares_pass_orbit: bool = False
    attitude_in_orbital_frame: bool = False

    # ---- time -------------------------------------------------------------------------------
    @property
    def time_variable(self) -> str:
        if self.earth_fixed:
            return "t = L * line_time (s) since the first line"
        return "L (image line number); internally tau = L / 1000"

    def tau_per_line(self, line_time_s: float) -> float:
        """d tau / d L of this kind's time variable."""
        return line_time_s if self.earth_fixed else 1.0 / POLY_TIME_SCALE_LINES

    def attitude_time_offset(self, kc: np.ndarray) -> float:
        """Time (tau units) added to an image's tau to give its angle polynomials' time."""
        return 0.0

    @property
    def position_from_image_state(self) -> bool:
        """The image's own position parameters take its approximate state (or ``initial``)."""
        return self.has_camera and not self.shares_pass_orbit

    # ---- parameters -------------------------------------------------------------------------
    def order_elements(self) -> tuple[str, ...]:
        """Elements whose order a model's ``orders`` option may set."""
        return ANGLES if self.earth_fixed else ELEMENTS

    def parameters(self, model: PlatformModel, orders: tuple[int, ...]) -> list[ParameterSpec]:
        """The estimated parameters of ``model`` with these orders, in report order."""
        specs: list[ParameterSpec] = []
        for e in ELEMENTS:
            is_angle = e in ANGLES
            for k in range(orders[ELEMENTS.index(e)] + 1):
                name = (e if k == 0 else f"{e}{k}") if is_angle else f"{e}{k}"
                base = "deg" if is_angle else "m"
                unit = base if k == 0 else (f"{base}/line" if k == 1 else f"{base}/line^{k}")
                scale = (_DEG if is_angle else 1.0) / POLY_TIME_SCALE_LINES**k
                specs.append(ParameterSpec(name, unit, coef_index(e, k), scale))
        return specs


@dataclass(frozen=True)
class OrbitKind(PlatformKind):
    """Earth-fixed orbit kinds: an ECEF state (or the pass's) and angle polynomials in seconds."""

    earth_fixed: bool = True
    numbered_rates: bool = False  # Kepler naming: kappa rates d1, d2; other angles omega1...

    def attitude_time_offset(self, kc: np.ndarray) -> float:
        # pass images whose attitude is one set per camera: time since the pass reference epoch
        return float(kc[PASS_ATT_OFF]) if self.shares_pass_orbit else 0.0

    def parameters(self, model: PlatformModel, orders: tuple[int, ...]) -> list[ParameterSpec]:
        specs: list[ParameterSpec] = []
        if self.ecef_state:
            for e in ("X", "Y", "Z"):
                specs.append(ParameterSpec(f"{e}0", "m", coef_index(e, 0), 1.0))
            for e, u in zip(("X", "Y", "Z"), ("ux", "uy", "uz")):
                specs.append(ParameterSpec(u, "m/s", coef_index(e, 1), 1.0))
        for e, shown in zip(ANGLES, model.angle_names):
            for k in range(orders[ELEMENTS.index(e)] + 1):
                if self.numbered_rates:
                    name = e if k == 0 else (f"d{k}" if e == "kappa" else f"{e}{k}")
                else:
                    name = shown if k == 0 else f"{shown}{k}"
                unit = "deg" if k == 0 else f"deg/s^{k}" if k > 1 else "deg/s"
                specs.append(ParameterSpec(name, unit, coef_index(e, k), _DEG))
        return specs


@dataclass(frozen=True)
class RpcKind(PlatformKind):
    """The image's RPC plus an image-space bias: no camera, no platform, no time variable."""

    has_camera: bool = False

    @property
    def time_variable(self) -> str:
        return "none (the RPC maps the ground to the image; bias in image coordinates)"

    def tau_per_line(self, line_time_s: float) -> float:
        return 0.0

    def order_elements(self) -> tuple[str, ...]:
        return ()

    def parameters(self, model: PlatformModel, orders: tuple[int, ...]) -> list[ParameterSpec]:
        return [ParameterSpec(name, unit, slot, 1.0) for name, unit, slot in model.bias]


POLYNOMIAL = PlatformKind("polynomial", KIND_POLYNOMIAL)
KEPLER = OrbitKind("kepler", KIND_KEPLER, ecef_state=True, numbered_rates=True)
ORBIT_ATTITUDE = OrbitKind("orbit-attitude", KIND_ORBIT_ATTITUDE, ecef_state=True, attitude_in_orbital_frame=True)
PASS = OrbitKind("pass", KIND_PASS, shares_pass_orbit=True, attitude_in_orbital_frame=True)
RPC_BIAS = RpcKind("rpc-bias", KIND_RPC)


_KINDS: dict[str, PlatformKind] = {}


def register_kind(kind: PlatformKind) -> PlatformKind:
    """Make a kind known (``all_kinds``, docs); its name must be new."""
    if kind.name in _KINDS:
        raise ValueError(f"platform kind {kind.name!r} registered twice")
    _KINDS[kind.name] = kind
    return kind


def all_kinds() -> list[PlatformKind]:
    return list(_KINDS.values())


for _kind in (POLYNOMIAL, KEPLER, ORBIT_ATTITUDE, PASS, RPC_BIAS):
    register_kind(_kind)
