"""Screening of a vendor's ephemeris before use: the frame of its velocities, duplicated
samples, gaps, and positions that stop agreeing with the velocities (a GPS receiver that lost
lock while the platform kept extrapolating). Bad samples are named and never used silently;
a conversion is stated.

Consistency of two neighbouring states (t0, P0, V0) and (t1, P1, V1), ECEF metres and m/s,
``dt = t1 - t0``: the quintic Hermite identity

    P1 - P0 = dt/2 (V0 + V1) + dt^2/12 (A0 - A1) + O(dt^5)

with ``A`` the acceleration in the Earth-fixed frame (gravity with the zonal terms J2-J4,
Coriolis and centrifugal: :func:`solver.simulate.orbit.acceleration_ecef`). Its residual is
centimetres for 1-s GPS states (0.42 m at most on 10 public CBERS-4/4A and Amazonia-1 records),
millimetres for 30-s DORIS states (the public SPOT 5 segment) and 20-ms Maxar states, and
2-10 m for the 60-s states of SPOT 1-4 scenes (seven public scenes of 1994-2012: their
velocities agree with the derivative of their positions to 0.1-0.2 m/s); the public CBERS-4A
WFI record of 2020-08-01 has 8.4 m at the first bad interval, growing by 8.3 m a second (its
positions continue on a straight line, without gravity, from the 67th state on). An interval
is inconsistent above ``CONSISTENCY_TOL_M + CONSISTENCY_TOL_M_S * dt`` (1.25 m for 1-s states,
16 m for 60-s ones).

**The velocities' frame.** The velocities of SPOT 1-4 DIMAP files are *inertial* velocities
expressed in Earth-fixed axes (``v_inertial = v_ecef + omega x P``): read as Earth-fixed, every
interval of those scenes misses by 24-27 km; as ``V - omega x P`` by 2-10 m. :func:`screen`
computes both residuals and converts (``velocities_m_s``, with a note saying so) when the
inertial reading is consistent and the Earth-fixed one is not; whatever the reader expects.

The samples kept are the longest run of consecutive consistent intervals; the others are
reported. :func:`propagate` replaces states the image needs but the file cannot give by the
orbit integrated from the nearest kept state (same force model; 0.2-0.3 m over 45-50 s on the
kept part of that record).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta

import numpy as np

from solver.sensors.linescan import OMEGA_EARTH_RAD_S
from solver.simulate.orbit import EarthModel, Orbit, acceleration_ecef

CONSISTENCY_TOL_M = 1.0  # Hermite residual of an interval above which it is inconsistent: this ...
CONSISTENCY_TOL_M_S = 0.25  # ... plus this times the interval (s): velocities off by 0.25 m/s (SPOT 1-4: 0.1-0.2 m/s)
EARTH = EarthModel()  # WGS 84 with the zonal terms J2-J4
GAP_FACTOR = 1.5  # an interval this many times the median one is a gap (reported)
INERTIAL_RATIO = 10.0  # V - omega x P must be this much more consistent than V to be taken as inertial
MIN_RATE_INTERVAL_S = 10.0  # velocity consistency (residual / dt) is measured on intervals this long at least (shorter: position rounding)
EARTH_FIXED, INERTIAL = "earth-fixed", "inertial"


def hermite_residuals(times_s: np.ndarray, positions_m: np.ndarray, velocities_m_s: np.ndarray) -> np.ndarray:
    """Residual (m) of each interval between neighbouring samples (module docstring), (n - 1,)."""
    a = acceleration_ecef(EARTH, positions_m, velocities_m_s)
    dt = np.diff(times_s)[:, None]
    pred = dt / 2 * (velocities_m_s[1:] + velocities_m_s[:-1]) + dt**2 / 12 * (a[:-1] - a[1:])
    return np.linalg.norm(np.diff(positions_m, axis=0) - pred, axis=1)


def tolerance_m(dt_s: np.ndarray) -> np.ndarray:
    """The largest Hermite residual (m) of a consistent interval of ``dt_s`` seconds."""
    return CONSISTENCY_TOL_M + CONSISTENCY_TOL_M_S * np.asarray(dt_s, float)


def earth_fixed(positions_m: np.ndarray, inertial_m_s: np.ndarray) -> np.ndarray:
    """Earth-fixed velocities of inertial velocities given in Earth-fixed axes: ``V - omega x P``."""
    return inertial_m_s - np.cross([0.0, 0.0, OMEGA_EARTH_RAD_S], positions_m)


@dataclass
class EphemerisScreen:
    """What the screening kept, converted, and why it dropped the others."""

    kept: np.ndarray  # (n,) bool: samples used
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # conversions (not faults of the file)
    dropped_duplicates: list[int] = field(default_factory=list)  # 0-based sample indices
    dropped_inconsistent: list[int] = field(default_factory=list)
    residuals_m: np.ndarray = field(default_factory=lambda: np.zeros(0))  # of the kept-of-duplicates samples, after conversion
    velocities_m_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (n, 3) Earth-fixed (converted when needed)
    velocity_frame: str = EARTH_FIXED  # the frame the file's velocities were found in
    velocity_rms_m_s: float | None = None  # RMS residual / interval of the kept intervals of MIN_RATE_INTERVAL_S or more


def label(epoch: datetime, t: float) -> str:
    """The UTC instant ``t`` seconds after ``epoch``, ISO 8601 to the millisecond."""
    return (epoch + timedelta(seconds=float(t))).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _velocity_frame(t: np.ndarray, p: np.ndarray, v: np.ndarray, what: str) -> tuple[np.ndarray, str, list[str]]:
    """The Earth-fixed velocities, the frame the given ones were found in, and the note of a
    conversion (module docstring)."""
    if t.size < 2:
        return v, EARTH_FIXED, []
    fixed = hermite_residuals(t, p, v)
    converted = earth_fixed(p, v)
    inertial = hermite_residuals(t, p, converted)
    tol = tolerance_m(np.diff(t))
    if np.median(inertial) * INERTIAL_RATIO < np.median(fixed) and np.median(inertial / tol) <= 1.0:
        dt = float(np.median(np.diff(t)))
        note = (f"{what}: the velocities are inertial velocities in Earth-fixed axes (as Earth-fixed velocities they miss "
                f"the positions by {fixed.min() / 1e3:.1f}-{fixed.max() / 1e3:.1f} km per {dt:g}-s interval, as V - omega x P "
                f"by {inertial.min():.2f}-{inertial.max():.2f} m): converted to Earth-fixed velocities, V - omega x P")
        return converted, INERTIAL, [note]
    return v, EARTH_FIXED, []


def screen(times_s: np.ndarray, positions_m: np.ndarray, velocities_m_s: np.ndarray, epoch: datetime,
           what: str = "ephemeris", tol_m: float | None = None) -> EphemerisScreen:
    """The frame of the velocities (converted to Earth-fixed when found inertial), duplicated
    samples (same time), gaps and states inconsistent with their neighbours. A sample repeating
    an earlier time is dropped (warned; its values are compared with the first); of the rest,
    the longest run of consistent intervals is kept and every other sample named in a warning.
    Times must otherwise increase (the caller refuses them when not). ``tol_m``: one tolerance
    (m) for every interval in place of :func:`tolerance_m`."""
    n = times_s.size
    kept = np.ones(n, bool)
    out = EphemerisScreen(kept)
    for k in range(1, n):
        same = np.flatnonzero(kept[:k] & (times_s[:k] == times_s[k]))
        if same.size:
            kept[k] = False
            out.dropped_duplicates.append(k)
            j = int(same[0])
            differ = float(np.linalg.norm(positions_m[k] - positions_m[j]))
            out.warnings.append(f"{what}: sample {k + 1} repeats the time {label(epoch, times_s[k])} of sample {j + 1}"
                                + (f" with a position {differ:.3f} m away" if differ > 1e-3 else " (identical)")
                                + ": dropped")
    idx = np.flatnonzero(kept)
    t, p = times_s[idx], positions_m[idx]
    v, out.velocity_frame, out.notes = _velocity_frame(t, p, velocities_m_s[idx], what)
    out.velocities_m_s = np.array(velocities_m_s, float)
    out.velocities_m_s[idx] = v
    dup = np.array(out.dropped_duplicates, int)
    if dup.size and out.velocity_frame == INERTIAL:
        out.velocities_m_s[dup] = earth_fixed(positions_m[dup], velocities_m_s[dup])
    dt = np.diff(t)
    if dt.size:
        gaps = np.flatnonzero(dt > GAP_FACTOR * np.median(dt))
        for g in gaps:
            out.warnings.append(f"{what}: a gap of {dt[g]:g} s between samples {idx[g] + 1} and {idx[g + 1] + 1} "
                                f"({label(epoch, t[g])} to {label(epoch, t[g + 1])}; the others are {np.median(dt):g} s apart)")
    res = hermite_residuals(t, p, v)
    out.residuals_m = res
    tol_each = tolerance_m(dt) if tol_m is None else np.full(dt.shape, tol_m)
    good = res <= tol_each
    best_start, best_len, start = 0, 0, None
    for i, g in enumerate(np.append(good, False)):
        if g and start is None:
            start = i
        elif not g and start is not None:
            if i - start > best_len:
                best_start, best_len = start, i - start
            start = None
    keep_idx = idx[:0] if best_len == 0 and idx.size > 1 else idx[best_start:best_start + best_len + 1]
    run = slice(best_start, best_start + best_len)
    long = dt[run] >= MIN_RATE_INTERVAL_S
    if np.any(long):
        out.velocity_rms_m_s = float(np.sqrt(np.mean((res[run][long] / dt[run][long]) ** 2)))
    bad = np.setdiff1d(idx, keep_idx)
    if bad.size:
        kept[bad] = False
        out.dropped_inconsistent = [int(b) for b in bad]
        worst = float(res[~good].max()) if np.any(~good) else 0.0
        first_bad = float(res[~good][0]) if np.any(~good) else 0.0
        tol = float(np.median(tol_each))
        out.warnings.append(
            f"{what}: {bad.size} states ({_ranges(bad)}, {label(epoch, times_s[bad[0]])} to "
            f"{label(epoch, times_s[bad[-1]])}) disagree with the velocities of their neighbours "
            f"({first_bad:.1f} m at the first inconsistent interval, {worst:.1f} m at the worst; "
            f"consistent states agree to {tol:.3g} m over {np.median(dt):g} s): not used")
    return out


def _ranges(idx: np.ndarray) -> str:
    """1-based sample numbers as ranges: ``samples 67-114``."""
    parts, start, prev = [], int(idx[0]), int(idx[0])
    for i in [int(v) for v in idx[1:]] + [None]:
        if i is not None and i == prev + 1:
            prev = i
            continue
        parts.append(f"{start + 1}" if start == prev else f"{start + 1}-{prev + 1}")
        if i is not None:
            start = prev = i
    return "samples " + ", ".join(parts)


def propagate(times_s: np.ndarray, positions_m: np.ndarray, velocities_m_s: np.ndarray,
              targets_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ECEF states (positions (m, 3), velocities (m, 3)) at ``targets_s`` integrated from the
    nearest of the given states (module docstring's force model)."""
    out_p, out_v = np.empty((targets_s.size, 3)), np.empty((targets_s.size, 3))
    nearest = np.abs(targets_s[:, None] - times_s[None, :]).argmin(axis=1)
    for k in np.unique(nearest):
        sel = nearest == k
        dt = targets_s[sel] - times_s[k]
        orbit = Orbit(EARTH, np.concatenate([positions_m[k], velocities_m_s[k]]), min(0.0, dt.min()), max(0.0, dt.max()))
        out_p[sel], out_v[sel] = orbit.state(dt)
    return out_p, out_v
