"""Polynomial platform models in the Local Geodetic System (time = line number).

Every exterior-orientation element is a polynomial of the image line L (seed 000 eqs 16-17,
seed 002 eq 2)::

    X(L) = X0 + X1 L + X2 L^2 (+ X3 L^3)      (same for Y, Z)
    omega(L), phi(L), kappa(L) likewise, or held at given values

Object space: LGS east-north-up at the centroid of the control points (metres). Internally the
polynomials use tau = L / 1000 for conditioning; reported coefficients are per line^k.
"""

from __future__ import annotations

from solver.platforms.kinds import POLYNOMIAL
from solver.platforms.registry import HELD, PlatformModel, register

_EQ = "X(L)=X0+X1 L+X2 L^2, Y, Z likewise; kappa(L)=kappa+kappa1 L(+kappa2 L^2)"
_HELD_ON = {"omega": 0.0, "phi": lambda pitch_deg: pitch_deg}
_HELD_DOC = {
    "omega_deg": "held omega (default 0)",
    "phi_deg": "held phi (default: the camera's mounting_pitch_deg, e.g. -23.8 backward)",
}

GENERAL = register(
    PlatformModel(
        name="GENERAL",
        title="General polynomial model (Gugan & Dowman 1988): all six elements polynomial",
        kind=POLYNOMIAL,
        frame="LGS",
        orders=(2, 2, 2, 2, 2, 2),
        order_option=True,
        reference="seed 000 eq 16",
        equations="each of X, Y, Z, omega, phi, kappa = sum_k c_k L^k, orders per element",
        options_doc={"orders": "{X,Y,Z,omega,phi,kappa: -1 (held at <e>_deg) .. 3}; default 2"},
        held_defaults={"omega": 0.0, "phi": lambda pitch_deg: pitch_deg, "kappa": 0.0},
    )
)

ON1 = register(
    PlatformModel(
        name="ON1",
        title="Orun & Natarajan: X, Y, Z quadratic, kappa linear, omega/phi held",
        kind=POLYNOMIAL,
        frame="LGS",
        orders=(2, 2, 2, HELD, HELD, 1),
        reference="seed 000 eq 17 (model 5)",
        equations=_EQ + "; omega, phi held (absolute constraints)",
        held_defaults=_HELD_ON,
        options_doc=_HELD_DOC,
    )
)

ON2 = register(
    PlatformModel(
        name="ON2",
        title="Orun & Natarajan: X, Y, Z, kappa quadratic, omega/phi held",
        kind=POLYNOMIAL,
        frame="LGS",
        orders=(2, 2, 2, HELD, HELD, 2),
        reference="seed 000 eqs 17, 23 (model 6); = seed 002 12-parameter model",
        equations=_EQ + "; omega, phi held (absolute constraints)",
        held_defaults=_HELD_ON,
        options_doc=_HELD_DOC,
    ),
    aliases=("MT12",),
)

P1 = register(
    PlatformModel(
        name="P1",
        title="Polynomial: X, Y, Z quadratic, kappa linear, omega/phi estimated constants",
        kind=POLYNOMIAL,
        frame="LGS",
        orders=(2, 2, 2, 0, 0, 1),
        reference="seed 000 model 7",
        equations=_EQ + "; omega, phi constants",
    )
)

P2 = register(
    PlatformModel(
        name="P2",
        title="Polynomial: X, Y, Z, kappa quadratic, omega/phi estimated constants",
        kind=POLYNOMIAL,
        frame="LGS",
        orders=(2, 2, 2, 0, 0, 2),
        reference="seed 000 model 8",
        equations=_EQ + "; omega, phi constants",
    )
)

MT8 = register(
    PlatformModel(
        name="MT8",
        title="Medeiros & Tommaselli 8 parameters: X, Y, Z, kappa linear, omega/phi held",
        kind=POLYNOMIAL,
        frame="LGS",
        orders=(1, 1, 1, HELD, HELD, 1),
        reference="seed 002 eq 2 (first order)",
        equations="X(L)=X0+X1 L (Y, Z likewise), kappa(L)=kappa+kappa1 L; omega, phi held",
        held_defaults=_HELD_ON,
        options_doc=_HELD_DOC,
    )
)
