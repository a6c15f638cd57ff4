"""The screening every reader applies (solver/sensors/screening.py, ephemeris_check.py), against
orbits and attitudes with known truth:

- the Hermite consistency of 30-s states of an orbit integrated with the check's force model is
  millimetres (its acceleration term is 19 m over 30 s: with its sign turned, the states would
  look 38 m inconsistent; 1-s states cannot tell, the term is 0.7 mm there);
- inertial velocities in Earth-fixed axes are found and converted; Earth-fixed ones left alone;
- a gap, a duplicated attitude time and a flipped attitude sample are named and dropped (or
  reported), and the model keeps the rest;
- samples spanning a leap second are refused.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timezone

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver.sensors.ephemeris_check import EARTH, EARTH_FIXED, INERTIAL, hermite_residuals, screen
from solver.sensors.errors import MetadataError
from solver.sensors.linescan import OMEGA_EARTH_RAD_S, Corrections, LinescanModel
from solver.sensors.screening import screen_model
from solver.sensors.xmlsafe import Node
from solver.simulate.orbit import Orbit

EPOCH = datetime(2020, 3, 1, 10, 0, 0, tzinfo=timezone.utc)
STATE0 = np.array([3.5e6, 2.6e6, 5.7e6, 5682.0, 1868.0, -4426.0])  # ECEF m, m/s: a SPOT-like state
SLERP_TWO_INTERVALS = 5e-4  # rotation matrix elements: a sample replaced by its neighbours' slerp (measured 1e-4)
CONSISTENT_30S_M = 0.05  # the Hermite residual of 30-s states of the integrated orbit (quintic truncation: ~1 cm)


def _states(step_s: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(n) * step_s
    p, v = Orbit(EARTH, STATE0, 0.0, float(t[-1])).state(t)
    return t, p, v


def test_30_s_states_of_an_integrated_orbit_are_consistent() -> None:
    t, p, v = _states(30.0, 11)
    res = hermite_residuals(t, p, v)
    assert res.max() < CONSISTENT_30S_M, res
    out = screen(t, p, v, EPOCH)
    assert out.kept.all() and not out.warnings and out.velocity_frame == EARTH_FIXED


def test_the_acceleration_term_matters_at_30_s_and_not_at_1_s() -> None:
    """Evidence of what the test above protects: the dt^2/12 (A0 - A1) term is tens of metres
    over 30 s and under a millimetre over 1 s (so only long intervals can catch its sign)."""
    from solver.simulate.orbit import acceleration_ecef

    for step, low, high in ((30.0, 5.0, 100.0), (1.0, 0.0, 1e-3)):
        t, p, v = _states(step, 5)
        a = acceleration_ecef(EARTH, p, v)
        term = np.linalg.norm(step**2 / 12 * (a[:-1] - a[1:]), axis=1)
        assert np.all((term > low) & (term < high)), (step, term)


def test_inertial_velocities_are_found_and_converted() -> None:
    t, p, v = _states(60.0, 8)
    inertial = v + np.cross([0.0, 0.0, OMEGA_EARTH_RAD_S], p)
    out = screen(t, p, inertial, EPOCH, "eph")
    assert out.velocity_frame == INERTIAL and out.kept.all()
    assert np.abs(out.velocities_m_s - v).max() < 1e-9
    assert "inertial velocities in Earth-fixed axes" in out.notes[0] and "V - omega x P" in out.notes[0]


def test_a_gap_is_reported() -> None:
    t, p, v = _states(10.0, 12)
    keep = np.r_[0:5, 8:12]  # samples 6-8 missing: a 40-s interval among 10-s ones
    out = screen(t[keep], p[keep], v[keep], EPOCH, "eph")
    assert out.kept.all() and any("a gap of 40 s between samples 5 and 6" in w for w in out.warnings), out.warnings


def _model(n_att: int = 50, flip: int | None = None, duplicate: int | None = None) -> LinescanModel:
    t, p, v = _states(1.0, 20)
    ta = np.linspace(2.0, 17.0, n_att)
    rot = Rotation.from_euler("xyz", np.column_stack([0.01 * ta, 0.002 * np.sin(ta), 0.3 + 0 * ta]))
    q = rot.as_quat()[:, [3, 0, 1, 2]]
    if flip is not None:
        q[flip] = Rotation.from_euler("x", 0.3).as_quat()[[3, 0, 1, 2]]
    if duplicate is not None:
        ta = ta.copy()
        ta[duplicate] = ta[duplicate - 1]
    return LinescanModel(lines=1000, columns=100, epoch_utc="2020-03-01T10:00:00Z", tlc_lines=np.array([0.0, 1.0]),
                         tlc_times_s=np.array([4.0, 4.01]), ephemeris_times_s=t, positions_ecef_m=p, velocities_ecef_m_s=v,
                         attitude_times_s=ta, attitude_wxyz=q, look_body=lambda c: np.column_stack([0 * c, c, 1 + 0 * c]),
                         corrections=Corrections(False, False, False))


def _node(name: str) -> Node:
    import xml.etree.ElementTree as ET

    return Node(ET.Element(name), name, "f.xml")


def test_a_flipped_attitude_sample_is_dropped_and_named() -> None:
    model, s = screen_model(_model(flip=20), _node("eph"), _node("att"))
    assert s.dropped_attitude == [20] and model.attitude_times_s.size == 49
    assert "1 samples (21," in s.warnings[0] and "not used" in s.warnings[0], s.warnings
    clean, s0 = screen_model(_model(), _node("eph"), _node("att"))
    assert s0.dropped_attitude == [] and not s0.warnings
    # what stays is the clean attitude: at the dropped sample's time the slerp of its neighbours,
    # within what two intervals of this curved attitude leave (measured 1e-4 rad), far from the flip
    t = _model().attitude_times_s[20:21]
    assert np.abs(model.rotation(t) - clean.rotation(t)).max() < SLERP_TWO_INTERVALS


def test_a_duplicated_attitude_time_is_dropped() -> None:
    model, s = screen_model(_model(duplicate=10), _node("eph"), _node("att"))
    assert s.dropped_attitude == [10] and "sample 11 repeats the time" in s.warnings[0]
    assert np.all(np.diff(model.attitude_times_s) > 0)


def test_samples_spanning_a_leap_second_are_refused() -> None:
    m = replace(_model(), epoch_utc="2016-12-31T23:59:55Z")
    with pytest.raises(MetadataError, match="leap second"):
        screen_model(m, _node("eph"), _node("att"))
