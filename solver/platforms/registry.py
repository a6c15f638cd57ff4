"""Platform-model registry: each model declares its parameters, units, frame and time variable.

A platform model maps the scaled time ``tau`` of an image line to the perspective-centre
position and the attitude angles (omega, phi, kappa). All models share one numerical form (see
:mod:`solver.kernels`): a full coefficient vector ``coef[6, 4]`` for the elements
(X, Y, Z, omega, phi, kappa) and powers tau^0..tau^3, of which a model frees a subset, holds some
at given values, and (Kepler kind) interprets coef[0:3, 0:2] as the Earth-fixed state vector.

Adding a model or a kind: docs/architecture.md, "Where new code goes" (the one checklist).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.platforms.kinds import (
    ANGLES,
    ELEMENTS,
    POLY_TIME_SCALE_LINES,
    ParameterSpec,
    PlatformKind,
    all_kinds,
    coef_index,
    register_kind,
)

HELD = -1  # order value meaning "held at a given value, not estimated"
# the state of a pass-propagated model (solver.observations.passes), ECEF at the pass reference epoch
PASS_STATE = (("X", "m"), ("Y", "m"), ("Z", "m"), ("VX", "m/s"), ("VY", "m/s"), ("VZ", "m/s"))


@dataclass(frozen=True)
class PlatformModel:
    """A registered platform model.

    ``orders`` gives for each element (X, Y, Z, omega, phi, kappa) the polynomial order that is
    estimated, or HELD (-1) for an element held at a given value (``held_defaults``, degrees, or
    a callable of the camera returning degrees). For the Kepler kind the X, Y, Z orders are
    ignored: the state vector (X0, Y0, Z0, ux, uy, uz) is always estimated.
    """

    name: str
    title: str
    kind: PlatformKind  # what the stages ask (solver.platforms.kinds); kind.kernel for the kernels
    frame: str  # "LGS" or "ECEF"
    orders: tuple[int, int, int, int, int, int]
    reference: str
    equations: str
    j2: bool = False
    held_defaults: dict[str, Any] = field(default_factory=dict)
    options_doc: dict[str, str] = field(default_factory=dict)
    order_option: bool = False  # GENERAL: orders come from job options
    angle_names: tuple[str, str, str] = ("omega", "phi", "kappa")
    # RPC bias models (kind RPC_BIAS): the estimated bias parameters, each (name, unit, coef slot)
    bias: tuple[tuple[str, str, int], ...] = ()

    @property
    def time_variable(self) -> str:
        return self.kind.time_variable

    def tau_per_line(self, line_time_s: float) -> float:
        """d tau / d L for this model."""
        return self.kind.tau_per_line(line_time_s)

    # ---- parameters -----------------------------------------------------------------------
    @property
    def option_names(self) -> frozenset[str]:
        """The options this model takes: those documented, and ``<angle>_deg`` of the angles it
        can hold."""
        return frozenset(self.options_doc) | {f"{e}_deg" for e in self.held_defaults}

    def order_elements(self) -> tuple[str, ...]:
        """Elements whose order the ``orders`` option sets (orbital kinds: the angles only)."""
        if not self.order_option:
            return ()
        return self.kind.order_elements()

    def effective_orders(self, options: dict[str, Any]) -> tuple[int, ...]:
        if not self.order_option:
            return self.orders
        given = dict(zip(ELEMENTS, self.orders))
        for k, v in (options.get("orders") or {}).items():
            if k not in given:
                raise ValueError(f"unknown element {k!r} in orders (use {', '.join(ELEMENTS)})")
            if not isinstance(v, int) or not (HELD <= v <= 3):
                raise ValueError(f"order of {k} must be an integer from -1 (held) to 3")
            given[k] = v
        return tuple(given[e] for e in ELEMENTS)

    def parameters(self, options: dict[str, Any] | None = None) -> list[ParameterSpec]:
        """The estimated parameters, in report order."""
        return self.kind.parameters(self, self.effective_orders(options or {}))

    def free_indices(self, options: dict[str, Any] | None = None) -> np.ndarray:
        return np.array([p.index for p in self.parameters(options)], dtype=np.int64)

    def held_values_rad(self, options: dict[str, Any], camera_pitch_deg: float) -> dict[str, float]:
        """Values (rad) of the held angle elements, from options ``<angle>_deg`` or defaults."""
        orders = self.effective_orders(options)
        out = {}
        for e in ANGLES:
            if orders[ELEMENTS.index(e)] != HELD:
                continue
            default = self.held_defaults.get(e, 0.0)
            if callable(default):
                default = default(camera_pitch_deg)
            value = options.get(f"{e}_deg", default)
            out[e] = math.radians(float(value))
        return out

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "title": self.title,
            "frame": self.frame,
            "time_variable": self.time_variable,
            "parameters": [{"name": p.name, "unit": p.unit} for p in self.parameters({})],
            "pass_parameters": [{"name": n, "unit": u} for n, u in PASS_STATE] if self.kind.shares_pass_orbit else [],
            "held": sorted(self.held_defaults),
            "options": self.options_doc,
            "reference": self.reference,
            "equations": self.equations,
        }


_REGISTRY: dict[str, PlatformModel] = {}


def register(model: PlatformModel, aliases: tuple[str, ...] = ()) -> PlatformModel:
    for key in (model.name, *aliases):
        k = key.upper()
        if k in _REGISTRY:
            raise ValueError(f"platform model {key!r} registered twice")
        _REGISTRY[k] = model
    return model


def get_model(name: str) -> PlatformModel:
    """Look a model up by name (case-insensitive); KeyError lists the known names."""
    try:
        return _REGISTRY[name.upper()]
    except KeyError:
        raise KeyError(f"unknown platform model {name!r}; known: {', '.join(model_names())}") from None


def model_names() -> list[str]:
    seen: dict[str, None] = {}
    for m in _REGISTRY.values():
        seen.setdefault(m.name, None)
    return list(seen)


def aliases(model: PlatformModel) -> list[str]:
    """The other names a job may call ``model`` by (as registered, upper case)."""
    return [k for k, m in _REGISTRY.items() if m is model and k != model.name.upper()]


def all_models() -> list[PlatformModel]:
    return [get_model(n) for n in model_names()]


__all__ = [
    "ANGLES",
    "ELEMENTS",
    "HELD",
    "PASS_STATE",
    "POLY_TIME_SCALE_LINES",
    "PlatformKind",
    "all_kinds",
    "register_kind",
    "ParameterSpec",
    "PlatformModel",
    "all_models",
    "coef_index",
    "get_model",
    "model_names",
    "register",
]
