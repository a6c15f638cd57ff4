"""UCL Kepler and J2-perturbed platform models in the Earth-fixed frame (seed 000 section 4.1).

Position of the perspective centre, second-order Taylor expansion about the first line::

    S(t) = S0 + u t + 1/2 a t^2,   t = L * line_time (s)
    a = g(S0) + Omega^2 (X0, Y0, 0) + 2 Omega (u_y, -u_x, 0)
    g = -GM S0 / r^3                                   (K1, K2)
    g += -3/2 J2 GM a_e^2 / r^5 (X0 (1 - 5 Z0^2/r^2), Y0 (1 - 5 Z0^2/r^2), Z0 (3 - 5 Z0^2/r^2))
                                                       (J2-1, J2-2)

S0 = (X0, Y0, Z0), u = (ux, uy, uz) in ECEF (WGS 84 / ITRF). Seed 000 prints the Coriolis term of
Y with the wrong sign, halves only the gravity term (eq 19) or nothing (eq 21), and gives the J2
Z factor as (1 - 5 Z^2/r^2); the form above is the physically correct one (docs/models.md).

Attitude: omega, phi constant, kappa = kappa + d1 t (+ d2 t^2). Deviation from the papers: the
angles are measured from the LGS axes (east, north, up at the control centroid) instead of the
ECEF axes; the rotation is the same set of matrices reparametrised by a constant rotation, but
the ECEF parametrisation is near gimbal lock for a forward-looking camera on a descending pass
at southern latitudes (phi close to -90 deg), which ruins conditioning.
"""

from __future__ import annotations

from solver.geometry.geodesy import A_WGS84_M
from solver.platforms.kinds import KEPLER
from solver.platforms.registry import PlatformModel, register

GM_M3_S2 = 3.986005e14  # seed 000 (GRS80)
OMEGA_RAD_S = 7.292115e-5
J2 = 1.08263e-3
AE_M = A_WGS84_M  # the semi-major axis (the same in GRS80 and WGS 84)

_EQ = "S(t)=S0+u t+1/2 a(S0,u) t^2 (ECEF, rotating frame); omega, phi const; kappa poly in t"

K1 = register(
    PlatformModel(
        name="K1",
        title="UCL Kepler (Earth-fixed), kappa linear",
        kind=KEPLER,
        frame="ECEF",
        orders=(1, 1, 1, 0, 0, 1),
        reference="seed 000 eq 19 (model 1), seed 001 eqs 34-37",
        equations=_EQ,
    )
)
K2 = register(
    PlatformModel(
        name="K2",
        title="UCL Kepler (Earth-fixed), kappa quadratic",
        kind=KEPLER,
        frame="ECEF",
        orders=(1, 1, 1, 0, 0, 2),
        reference="seed 000 eqs 19-20 (model 2)",
        equations=_EQ,
    )
)
J2_1 = register(
    PlatformModel(
        name="J2-1",
        title="J2-perturbed orbit (Earth-fixed), kappa linear",
        kind=KEPLER,
        frame="ECEF",
        orders=(1, 1, 1, 0, 0, 1),
        j2=True,
        reference="seed 000 eqs 21-22 (model 3)",
        equations=_EQ + "; g includes J2",
    ),
    aliases=("J21",),
)
J2_2 = register(
    PlatformModel(
        name="J2-2",
        title="J2-perturbed orbit (Earth-fixed), kappa quadratic",
        kind=KEPLER,
        frame="ECEF",
        orders=(1, 1, 1, 0, 0, 2),
        j2=True,
        reference="seed 000 model 4",
        equations=_EQ + "; g includes J2",
    ),
    aliases=("J22",),
)
