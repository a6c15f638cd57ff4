"""Numerical orbit in the Earth-fixed frame (WGS 84 ECEF, EPSG:4978 axes).

Force model (per unit mass), integrated directly in the rotating frame::

    a = grad U(r) - 2 Omega x v - Omega x (Omega x r)
    U(r) = GM / r * [1 - sum_{n=2..4} J_n (a_e / r)^n P_n(z / r)]

with Omega = (0, 0, omega_E). ``P_n`` are Legendre polynomials; U is the positive geopotential
(``a = grad U``). The zonal coefficients are EGM2008's (``J_n = -sqrt(2n + 1) * Cbar_n0``):

    J2 = 1.0826261738522e-3, J3 = -2.5324105185677e-6, J4 = -1.6198975999170e-6

(tide-free Cbar_20 = -4.84165143790815e-4, Cbar_30 = 9.57161207093473e-7, Cbar_40 =
5.39965866638991e-7)

and GM = 3.986004418e14 m^3/s^2, a_e = 6378137 m, omega_E = 7.292115e-5 rad/s (WGS 84 /
IERS). Drag, third bodies, tesseral terms, precession and nutation are not modelled: over the
minutes of one pass they are far below what a single image can resolve.

The inertial frame used to set up initial conditions (and by the invariant tests) is the ECEF
frame frozen at ``t_s = 0``: ``r_eci = Rz(omega_E t) r_ecef``.

Units: metres, seconds, radians. Arrays of states are (n, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from solver.geometry.geodesy import A_WGS84_M, geodetic_to_ecef

# EGM2008 normalized zonal coefficients Cbar_n0, n = 2, 3, 4
_CBAR_N0 = {2: -4.84165143790815e-4, 3: 9.57161207093473e-7, 4: 5.39965866638991e-7}
J_EGM2008 = {n: -np.sqrt(2 * n + 1) * c for n, c in _CBAR_N0.items()}

DAY_S = 86400.0
TROPICAL_YEAR_DAYS = 365.2422


@dataclass(frozen=True)
class EarthModel:
    """Gravity and rotation of the Earth.

    ``zonal`` maps degree n to the unnormalized zonal coefficient J_n (dimensionless).
    """

    gm_m3_s2: float = 3.986004418e14
    radius_m: float = A_WGS84_M
    omega_rad_s: float = 7.292115e-5
    zonal: dict[int, float] = field(default_factory=lambda: dict(J_EGM2008))

    def point_mass(self) -> "EarthModel":
        """The same Earth without zonal terms."""
        return replace(self, zonal={})

    def only(self, degrees: tuple[int, ...]) -> "EarthModel":
        """Keep only the listed zonal degrees (e.g. ``(2,)`` for J2 only)."""
        return replace(self, zonal={n: self.zonal[n] for n in degrees})

    @property
    def omega_vec(self) -> np.ndarray:
        return np.array([0.0, 0.0, self.omega_rad_s])


def _legendre(u: np.ndarray, n_max: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Legendre polynomials P_n(u) and derivatives P_n'(u) for n = 0..n_max."""
    p = [np.ones_like(u), u]
    dp = [np.zeros_like(u), np.ones_like(u)]
    for n in range(1, n_max):
        p.append(((2 * n + 1) * u * p[n] - n * p[n - 1]) / (n + 1))
        dp.append(dp[n - 1] + (2 * n + 1) * p[n])
    return p, dp


def potential(earth: EarthModel, r_ecef_m: np.ndarray) -> np.ndarray:
    """Geopotential U (m^2/s^2, positive, gravity = grad U) at ECEF positions (n, 3) -> (n,)."""
    r_vec = np.atleast_2d(r_ecef_m)
    r = np.linalg.norm(r_vec, axis=1)
    u = r_vec[:, 2] / r
    out = np.ones_like(r)
    if earth.zonal:
        p, _ = _legendre(u, max(earth.zonal))
        for n, jn in earth.zonal.items():
            out -= jn * (earth.radius_m / r) ** n * p[n]
    return earth.gm_m3_s2 / r * out


def gravity(earth: EarthModel, r_ecef_m: np.ndarray) -> np.ndarray:
    """Gravitational acceleration grad U (m/s^2) at ECEF positions (n, 3) -> (n, 3)."""
    r_vec = np.atleast_2d(r_ecef_m)
    r = np.linalg.norm(r_vec, axis=1)[:, None]
    gm = earth.gm_m3_s2
    acc = -gm * r_vec / r**3
    if earth.zonal:
        z = r_vec[:, 2:3]
        u = z / r
        p, dp = _legendre(u, max(earth.zonal))
        e_z = np.array([0.0, 0.0, 1.0])
        du_dx = e_z / r - z * r_vec / r**3  # gradient of u = z / r
        for n, jn in earth.zonal.items():
            an = earth.radius_m**n
            # d/dx of r^-(n+1) P_n(u)
            d = -(n + 1) * r ** (-(n + 3)) * r_vec * p[n] + r ** (-(n + 1)) * dp[n] * du_dx
            acc -= gm * jn * an * d
    return acc


def acceleration_ecef(earth: EarthModel, r_ecef_m: np.ndarray, v_ecef_m_s: np.ndarray) -> np.ndarray:
    """Total acceleration in the rotating frame: gravity + Coriolis + centrifugal (n, 3)."""
    w = earth.omega_vec
    r_vec = np.atleast_2d(r_ecef_m)
    v_vec = np.atleast_2d(v_ecef_m_s)
    return gravity(earth, r_vec) - 2.0 * np.cross(w, v_vec) - np.cross(w, np.cross(w, r_vec))


def jacobi_integral(earth: EarthModel, r_ecef_m: np.ndarray, v_ecef_m_s: np.ndarray) -> np.ndarray:
    """Energy in the rotating frame, v^2/2 - omega^2 (x^2 + y^2)/2 - U (J/kg); conserved."""
    r_vec = np.atleast_2d(r_ecef_m)
    v_vec = np.atleast_2d(v_ecef_m_s)
    w2 = earth.omega_rad_s**2
    return (
        0.5 * np.sum(v_vec**2, axis=1)
        - 0.5 * w2 * (r_vec[:, 0] ** 2 + r_vec[:, 1] ** 2)
        - potential(earth, r_vec)
    )


def rot_z(angle_rad: np.ndarray) -> np.ndarray:
    """Active rotations about z by ``angle_rad`` (n,) -> (n, 3, 3)."""
    a = np.atleast_1d(angle_rad)
    c, s = np.cos(a), np.sin(a)
    m = np.zeros(a.shape + (3, 3))
    m[..., 0, 0] = c
    m[..., 0, 1] = -s
    m[..., 1, 0] = s
    m[..., 1, 1] = c
    m[..., 2, 2] = 1.0
    return m


def ecef_to_eci(
    earth: EarthModel, t_s: np.ndarray, r_ecef_m: np.ndarray, v_ecef_m_s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """ECEF states at times ``t_s`` to the inertial frame aligned with ECEF at t_s = 0."""
    m = rot_z(earth.omega_rad_s * np.atleast_1d(t_s))
    r_vec = np.atleast_2d(r_ecef_m)
    v_in = np.atleast_2d(v_ecef_m_s) + np.cross(earth.omega_vec, r_vec)
    return np.einsum("nij,nj->ni", m, r_vec), np.einsum("nij,nj->ni", m, v_in)


def sun_synchronous_semi_major_axis(earth: EarthModel, inclination_deg: float) -> float:
    """Semi-major axis (m) of a circular orbit whose J2 nodal drift follows the mean Sun.

    Solves ``-3/2 n J2 (a_e/a)^2 cos i = 2 pi / tropical year`` (mean elements, e = 0).
    """
    target = 2.0 * np.pi / (TROPICAL_YEAR_DAYS * DAY_S)
    cos_i = np.cos(np.radians(inclination_deg))
    if cos_i >= 0:
        raise ValueError("a sun-synchronous orbit is retrograde (inclination > 90 deg)")
    j2 = earth.zonal.get(2, J_EGM2008[2])
    # a^(7/2) = -3/2 sqrt(GM) J2 a_e^2 cos i / target
    return float((-1.5 * np.sqrt(earth.gm_m3_s2) * j2 * earth.radius_m**2 * cos_i / target) ** (2 / 7))


def circular_state_over(
    earth: EarthModel,
    lon_deg: float,
    lat_deg: float,
    semi_major_axis_m: float,
    inclination_deg: float,
    descending: bool = True,
) -> np.ndarray:
    """ECEF state (6,) at t_s = 0 of a circular orbit directly above a geodetic lon/lat.

    The satellite is put on the ellipsoid normal of (lon, lat) at radius ``semi_major_axis_m``
    with the circular speed sqrt(GM/a) in the inertial frame, moving south if ``descending``.
    """
    r0 = semi_major_axis_m
    h = r0 - np.linalg.norm(geodetic_to_ecef(np.array([[lon_deg, lat_deg, 0.0]]))[0])
    for _ in range(6):  # put the point on the normal at the height that gives radius r0
        p = geodetic_to_ecef(np.array([[lon_deg, lat_deg, h]]))[0]
        h += r0 - np.linalg.norm(p)
    lat_c = np.arcsin(p[2] / np.linalg.norm(p))
    lon = np.arctan2(p[1], p[0])
    inc = np.radians(inclination_deg)
    s = np.sin(lat_c) / np.sin(inc)
    if abs(s) > 1:
        raise ValueError(f"latitude {lat_deg} not reached with inclination {inclination_deg}")
    u = np.pi - np.arcsin(s) if descending else np.arcsin(s)  # argument of latitude
    raan = lon - np.arctan2(np.cos(inc) * np.sin(u), np.cos(u))
    cO, sO, ci, si = np.cos(raan), np.sin(raan), np.cos(inc), np.sin(inc)

    def pos(uu: float) -> np.ndarray:
        cu, su = np.cos(uu), np.sin(uu)
        return np.array([cO * cu - sO * su * ci, sO * cu + cO * su * ci, su * si])

    r_eci = r0 * pos(u)
    dir_v = np.array([-cO * np.sin(u) - sO * np.cos(u) * ci, -sO * np.sin(u) + cO * np.cos(u) * ci, np.cos(u) * si])
    v_eci = np.sqrt(earth.gm_m3_s2 / r0) * dir_v
    v_ecef = v_eci - np.cross(earth.omega_vec, r_eci)
    return np.concatenate([r_eci, v_ecef])


class Orbit:
    """An orbit integrated from a state at t_s = 0 over ``[t_min_s, t_max_s]`` (DOP853).

    ``state(t_s)`` evaluates the dense output (vectorised); positions/velocities are ECEF.
    """

    def __init__(
        self,
        earth: EarthModel,
        state0_ecef: np.ndarray,
        t_min_s: float,
        t_max_s: float,
        rtol: float = 1e-12,
    ) -> None:
        if not t_min_s <= 0.0 <= t_max_s:
            raise ValueError("the integration span must contain t_s = 0")
        self.earth = earth
        self.state0 = np.asarray(state0_ecef, dtype=float).copy()
        self.t_min_s, self.t_max_s = float(t_min_s), float(t_max_s)
        atol = np.array([1e-6] * 3 + [1e-9] * 3)
        self._fwd = self._integrate(t_max_s, rtol, atol) if t_max_s > 0 else None
        self._bwd = self._integrate(t_min_s, rtol, atol) if t_min_s < 0 else None

    def _rhs(self, _t: float, y: np.ndarray) -> np.ndarray:
        acc = acceleration_ecef(self.earth, y[None, :3], y[None, 3:])[0]
        return np.concatenate([y[3:], acc])

    def _integrate(self, t_end: float, rtol: float, atol: np.ndarray):
        from scipy.integrate import solve_ivp  # scipy here, not at import: the pba command line (and the server) loads this module

        sol = solve_ivp(
            self._rhs, (0.0, t_end), self.state0, method="DOP853", rtol=rtol, atol=atol, dense_output=True
        )
        if not sol.success:
            raise RuntimeError(f"orbit integration failed: {sol.message}")
        return sol

    def state(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """ECEF position (n, 3) m and velocity (n, 3) m/s at times ``t_s`` (n,)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        if np.any(t < self.t_min_s - 1e-9) or np.any(t > self.t_max_s + 1e-9):
            raise ValueError(f"time outside the integrated span [{self.t_min_s}, {self.t_max_s}] s")
        out = np.empty((t.size, 6))
        pos_mask = t >= 0
        if np.any(pos_mask):
            out[pos_mask] = self._fwd.sol(t[pos_mask]).T if self._fwd else self.state0
        if np.any(~pos_mask):
            out[~pos_mask] = self._bwd.sol(t[~pos_mask]).T
        return out[:, :3], out[:, 3:]

    def n_steps(self) -> int:
        """Number of accepted integration steps (both directions)."""
        return sum(len(s.t) - 1 for s in (self._fwd, self._bwd) if s is not None)
