"""Pass-propagated orbit models: one integrated orbit for all images of a pass (issue 7).

Position: one Earth-fixed state x0 = (X, Y, Z, VX, VY, VZ) at the pass reference epoch (the
middle of the observed lines of all the pass's images), shared by every image of the pass and
propagated by numerical integration in ECEF (two-body + J2 for PASS-J2, two-body for PASS-K;
centrifugal and Coriolis terms; :mod:`solver.kernels.propagation`) to the epoch of each line,
``first_line_time_s + L * line_time``. Derivatives wrt x0 from the variational equations.

Rotation object -> camera: as the orbit-attitude models (:mod:`solver.platforms.orbit_attitude`),
``M(t) = Ry(mounting) Rx(roll) Ry(pitch) Rz(yaw) R_orbit(S(t), V(t))`` with the orbital frame from
the propagated state and roll, pitch, yaw polynomials in time, one set per camera of the pass
(option ``attitude: camera``, the default: time since the pass reference epoch, shared by all the
camera's images on the pass) or one per image (``attitude: image``: time since its first line).

Images join a pass by the model option ``pass`` (default ``"1"``); all images of a pass use the
same model and need ``first_line_time_s`` on a common time scale. The ephemeris or header state
of each image, when weighted (``options.ephemeris`` or ``approx_state`` sigmas), is an
observation of the propagated state at that image's first line.
"""

from __future__ import annotations

from solver.platforms.kinds import PASS
from solver.platforms.registry import PlatformModel, register

_EQ = (
    "x0 = (S, V) ECEF at the pass reference epoch; S(t) = RK4 integration of "
    "S'' = g(S) + Omega^2 (X, Y, 0) + 2 Omega (VY, -VX, 0); "
    "M = Ry(mount) Rx(roll) Ry(pitch) Rz(yaw) R_orbit(S(t), V(t))"
)
_OPTIONS = {
    "orders": "{omega (roll), phi (pitch), kappa (yaw): 0..3}; default 1, 1, 1 (linear drift)",
    "pass": "pass identifier: images with the same value share one orbit (default '1')",
    "attitude": "camera (default): one attitude polynomial per camera of a pass, in s since the pass "
    "reference epoch, shared by the camera's images; image: one set per image, in s since its first line",
}

PASS_K = register(
    PlatformModel(
        name="PASS-K",
        title="Pass-propagated two-body orbit (one state per pass), attitude relative to the orbital frame",
        kind=PASS,
        frame="ECEF",
        orders=(1, 1, 1, 1, 1, 1),
        angle_names=("roll", "pitch", "yaw"),
        reference="docs/models.md section 12 (variational equations); attitude as Kim & Dowman 2006",
        equations=_EQ + "; g point mass",
        order_option=True,
        options_doc=_OPTIONS,
    )
)
PASS_J2 = register(
    PlatformModel(
        name="PASS-J2",
        title="Pass-propagated J2 orbit (one state per pass), attitude relative to the orbital frame",
        kind=PASS,
        frame="ECEF",
        orders=(1, 1, 1, 1, 1, 1),
        angle_names=("roll", "pitch", "yaw"),
        j2=True,
        reference="docs/models.md section 12 (variational equations); attitude as Kim & Dowman 2006",
        equations=_EQ + "; g point mass + J2",
        order_option=True,
        options_doc=_OPTIONS,
    )
)
