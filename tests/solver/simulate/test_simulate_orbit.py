"""The simulator's orbit obeys its force model: invariants, gradients, precession."""

from __future__ import annotations

import numpy as np
import pytest
from utils.differences import central_difference

from solver.geometry.geodesy import ecef_to_geodetic
from solver.simulate.orbit import (
    EarthModel,
    Orbit,
    circular_state_over,
    ecef_to_eci,
    gravity,
    jacobi_integral,
    potential,
    sun_synchronous_semi_major_axis,
)

POTENTIAL_GRADIENT_M_S2 = 1e-8  # gravity vs the central-difference gradient of the potential
ZONAL_GRADIENT_REL = 1e-6  # the zonal part alone (~1e-2 m/s^2), relative to its size

J2_FORM_REL, J2_FORM_ABS = 1e-12, 1e-15  # the J2 acceleration vs its closed form: the same terms in another order
PRECESSION_REL = 0.01  # the nodal precession vs its first-order theory: higher zonal terms and averaging over 400 epochs
SITE_DEG = 1e-8  # the default orbit passes over the site: ~1 mm on the ground
INCLINATION_DEG = 1e-9  # the inclination of the default state: arccos of a unit vector's component

EARTH = EarthModel()
LON, LAT, INC = -51.39, -22.12, 98.16
A_SSO = sun_synchronous_semi_major_axis(EARTH, INC)
STATE0 = circular_state_over(EARTH, LON, LAT, A_SSO, INC, descending=True)
PERIOD_S = 2 * np.pi * np.sqrt(A_SSO**3 / EARTH.gm_m3_s2)

REL_INVARIANT = 1e-10  # relative drift allowed for conserved quantities over two orbits


def _states(orbit: Orbit, n: int = 1500) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.linspace(orbit.t_min_s, orbit.t_max_s, n)
    r, v = orbit.state(t)
    return t, r, v


def _inertial(earth: EarthModel, orbit: Orbit) -> tuple[np.ndarray, np.ndarray]:
    t, r, v = _states(orbit)
    return ecef_to_eci(earth, t, r, v)


def test_gravity_is_the_gradient_of_the_potential():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20, 3))
    pts *= (7.0e6 / np.linalg.norm(pts, axis=1))[:, None]
    h = 10.0  # metre step, central differences (rounding of U ~ 6e7 m^2/s^2 limits smaller steps)
    num = np.column_stack([central_difference(lambda d: potential(EARTH, pts + d), np.zeros(3), i, h) for i in range(3)])
    acc = gravity(EARTH, pts)
    # the zonal part alone (~1e-2 m/s^2) must match too, not only the dominant central term
    zonal = acc - gravity(EARTH.point_mass(), pts)
    zonal_num = num - gravity(EARTH.point_mass(), pts)
    assert np.max(np.abs(acc - num)) < POTENTIAL_GRADIENT_M_S2
    assert np.max(np.abs(zonal - zonal_num)) / np.max(np.abs(zonal)) < ZONAL_GRADIENT_REL


def test_j2_acceleration_matches_the_textbook_formula():
    # Vallado eq 8-30; note the z component has (3 - 5 z^2/r^2) (seed 000 eqs 10, 12, 21 misprint it)
    e2 = EARTH.only((2,))
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(10, 3)) * 4e6
    r = np.linalg.norm(pts, axis=1)
    x, y, z = pts.T
    k = -1.5 * e2.zonal[2] * e2.gm_m3_s2 * e2.radius_m**2 / r**5
    expect = np.column_stack([k * x * (1 - 5 * z**2 / r**2), k * y * (1 - 5 * z**2 / r**2), k * z * (3 - 5 * z**2 / r**2)])
    got = gravity(e2, pts) - gravity(e2.point_mass(), pts)
    np.testing.assert_allclose(got, expect, rtol=J2_FORM_REL, atol=J2_FORM_ABS)


def test_jacobi_integral_conserved_with_full_force_model():
    orbit = Orbit(EARTH, STATE0, -PERIOD_S, PERIOD_S)
    _, r, v = _states(orbit)
    c = jacobi_integral(EARTH, r, v)
    assert np.ptp(c) / abs(c[0]) < REL_INVARIANT
    # and the ECEF kinetic energy alone is far from constant (the test can fail)
    ke = 0.5 * np.sum(v**2, axis=1)
    assert np.ptp(ke) / ke[0] > 1e-4


def test_point_mass_conserves_inertial_angular_momentum_and_energy():
    e0 = EARTH.point_mass()
    orbit = Orbit(e0, STATE0, 0.0, 2 * PERIOD_S)
    ri, vi = _inertial(e0, orbit)
    h = np.cross(ri, vi)
    energy = 0.5 * np.sum(vi**2, axis=1) - e0.gm_m3_s2 / np.linalg.norm(ri, axis=1)
    assert np.max(np.linalg.norm(h - h[0], axis=1)) / np.linalg.norm(h[0]) < REL_INVARIANT
    assert np.ptp(energy) / abs(energy[0]) < REL_INVARIANT


def test_zonal_terms_keep_only_the_polar_angular_momentum():
    orbit = Orbit(EARTH, STATE0, 0.0, 2 * PERIOD_S)
    ri, vi = _inertial(EARTH, orbit)
    h = np.cross(ri, vi)
    hn = np.linalg.norm(h[0])
    energy = 0.5 * np.sum(vi**2, axis=1) - EARTH.gm_m3_s2 / np.linalg.norm(ri, axis=1)
    # axisymmetric field: no torque about z
    assert np.ptp(h[:, 2]) / hn < REL_INVARIANT
    # but the orbit plane moves and the two-body energy is not an integral any more
    assert np.ptp(h[:, 0]) / hn > 1e-5 and np.ptp(h[:, 1]) / hn > 1e-5
    assert np.ptp(energy) / abs(energy[0]) > 1e-5


def test_j2_nodal_precession_matches_theory_and_is_sun_synchronous():
    e2 = EARTH.only((2,))
    day = 86400.0
    orbit = Orbit(e2, STATE0, 0.0, day)

    def node(t: np.ndarray) -> float:  # orbit-averaged right ascension of the ascending node
        r, v = orbit.state(t)
        ri, vi = ecef_to_eci(e2, t, r, v)
        h = np.cross(ri, vi)
        return float(np.mean(np.unwrap(np.arctan2(h[:, 0], -h[:, 1]))))

    t1 = np.linspace(0.0, PERIOD_S, 400)
    rate = (node(t1 + day - PERIOD_S) - node(t1)) / (day - PERIOD_S)
    n = np.sqrt(e2.gm_m3_s2 / A_SSO**3)
    theory = -1.5 * n * e2.zonal[2] * (e2.radius_m / A_SSO) ** 2 * np.cos(np.radians(INC))
    assert rate == pytest.approx(theory, rel=PRECESSION_REL)
    assert np.degrees(rate) * day == pytest.approx(360 / 365.2422, rel=PRECESSION_REL)


def test_default_orbit_is_alos_like_and_descending_over_the_site():
    orbit = Orbit(EARTH, STATE0, -30.0, 30.0)
    r, v = orbit.state(np.array([-10.0, 0.0, 10.0]))
    llh = ecef_to_geodetic(r)
    assert llh[1, 0] == pytest.approx(LON, abs=SITE_DEG) and llh[1, 1] == pytest.approx(LAT, abs=SITE_DEG)
    assert 685e3 < llh[1, 2] < 705e3  # ~692 km
    assert llh[2, 1] < llh[1, 1] < llh[0, 1]  # descending
    ri, vi = ecef_to_eci(EARTH, np.zeros(1), r[1:2], v[1:2])
    h = np.cross(ri, vi)[0]
    assert np.degrees(np.arccos(h[2] / np.linalg.norm(h))) == pytest.approx(INC, abs=INCLINATION_DEG)
