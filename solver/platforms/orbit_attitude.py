"""Orbit-attitude models (Kim & Dowman 2006, cited by seeds 000 and 001), Earth-fixed frame.

Position: the UCL Kepler / J2 state (S0, u) with the rotating-frame acceleration, exactly as
the K and J2 models (solver/platforms/kepler.py). Rotation object -> camera::

    M(t) = Ry(mounting) Rx(roll) Ry(pitch) Rz(yaw) R_orbit(S(t), V(t))

R_orbit has rows x (along track: the Earth-fixed velocity without its radial part, which
follows the ground track, i.e. includes yaw steering), y = z x x, z (radial, away from the
Earth), computed from the platform's own position and velocity at each line. The mounting
pitch is the camera's fixed ``mounting_pitch_deg`` (PRISM -23.8 / 0 / +23.8); roll, pitch, yaw
are small attitude angles relative to the orbital frame, constants or polynomials in t.
Because the rotation turns with the orbit (~0.36 deg during a 6-s PRISM image), the fitted
state keeps its physical meaning (velocity close to the real 7.5 km/s), unlike the
position-rotation models whose angles are constant in the Earth-fixed frame.
"""

from __future__ import annotations

from solver.platforms.kinds import ORBIT_ATTITUDE
from solver.platforms.registry import PlatformModel, register

_EQ = "S(t)=S0+u t+1/2 a(S0,u) t^2 (ECEF); M = Ry(mount) Rx(roll) Ry(pitch) Rz(yaw) R_orbit(S(t), V(t))"

OA_K = register(
    PlatformModel(
        name="OA-K",
        title="Orbit-attitude, Kepler orbit: attitude relative to the orbital frame, yaw linear",
        kind=ORBIT_ATTITUDE,
        frame="ECEF",
        orders=(1, 1, 1, 0, 0, 1),
        angle_names=("roll", "pitch", "yaw"),
        reference="Kim & Dowman 2006; docs/models.md section 10",
        equations=_EQ,
        order_option=True,
        options_doc={"orders": "{omega (roll), phi (pitch), kappa (yaw): 0..3}; default 0, 0, 1"},
    )
)
OA_J2 = register(
    PlatformModel(
        name="OA-J2",
        title="Orbit-attitude, J2-perturbed orbit: attitude relative to the orbital frame, yaw linear",
        kind=ORBIT_ATTITUDE,
        frame="ECEF",
        orders=(1, 1, 1, 0, 0, 1),
        angle_names=("roll", "pitch", "yaw"),
        j2=True,
        reference="Kim & Dowman 2006; docs/models.md section 10",
        equations=_EQ + "; g includes J2",
        order_option=True,
        options_doc={"orders": "{omega (roll), phi (pitch), kappa (yaw): 0..3}; default 0, 0, 1"},
    )
)
