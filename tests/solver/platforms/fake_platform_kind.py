"""A platform kind that exists only for tests/solver/platforms/test_platform_kinds.py: LGS polynomials of the
time in seconds since the first line (``tau = L * line_time``) instead of the line number.

Everything a new kind brings is here: its kind object (time scale, parameter names and units),
its kernel (it shares the polynomial kernel's mathematics, so it names that dispatch code), one
model of it, and the registry lines. Nothing else in solver/ knows it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from solver.kernels.layout import KIND_POLYNOMIAL
from solver.platforms.kinds import ANGLES, ELEMENTS, ParameterSpec, PlatformKind, coef_index, register_kind
from solver.platforms.registry import PlatformModel, register

_DEG = 180.0 / math.pi


@dataclass(frozen=True)
class SecondsPolynomialKind(PlatformKind):
    """Every element a polynomial of t = L * line_time (s), in the LGS."""

    @property
    def time_variable(self) -> str:
        return "t = L * line_time (s) since the first line; LGS polynomials"

    def tau_per_line(self, line_time_s: float) -> float:
        return line_time_s

    def parameters(self, model: PlatformModel, orders: tuple[int, ...]) -> list[ParameterSpec]:
        specs = []
        for e in ELEMENTS:
            angle = e in ANGLES
            for k in range(orders[ELEMENTS.index(e)] + 1):
                base = "deg" if angle else "m"
                unit = base if k == 0 else f"{base}/s" if k == 1 else f"{base}/s^{k}"
                specs.append(ParameterSpec(f"{e}{k}", unit, coef_index(e, k), _DEG if angle else 1.0))
        return specs


def install() -> PlatformModel:
    """Register the kind and its model FAKE-S2 (the registry lines of a real kind's module)."""
    kind = register_kind(SecondsPolynomialKind("fake-seconds-polynomial", KIND_POLYNOMIAL))
    return register(
        PlatformModel(
            name="FAKE-S2",
            title="Test kind: LGS polynomials of the time in seconds, quadratic position, linear kappa",
            kind=kind,
            frame="LGS",
            orders=(2, 2, 2, 0, 0, 1),
            reference="tests/solver/platforms/fake_platform_kind.py",
            equations="X(t) = X0 + X1 t + X2 t^2 (Y, Z alike); kappa(t) = kappa0 + kappa1 t",
        )
    )
