"""Screening of a vendor's ephemeris before use: duplicated samples, and positions that stop
agreeing with the velocities (a GPS receiver that lost lock while the platform kept
extrapolating). Bad samples are named and never used silently.

Consistency of two neighbouring states (t0, P0, V0) and (t1, P1, V1), ECEF metres and m/s,
``dt = t1 - t0``: the quintic Hermite identity

    P1 - P0 = dt/2 (V0 + V1) + dt^2/12 (A0 - A1) + O(dt^5)

with ``A`` the acceleration in the Earth-fixed frame (gravity with the zonal terms J2-J4,
Coriolis and centrifugal: :func:`solver.simulate.orbit.acceleration_ecef`). Its residual is
centimetres for 1-s GPS states (0.42 m at most on 10 public CBERS-4/4A and Amazonia-1 records)
and millimetres for 30-s DORIS states (the public SPOT 5 segment) and 20-ms Maxar states; the public CBERS-4A WFI
record of 2020-08-01 has 8.4 m at the first bad interval, growing by 8.3 m a second (its
positions continue on a straight line, without gravity, from the 67th state on).

The samples kept are the longest run of consecutive consistent intervals; the others are
reported. :func:`propagate` replaces states the image needs but the file cannot give by the
orbit integrated from the nearest kept state (same force model; 0.2-0.3 m over 45-50 s on the
kept part of that record).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta

import numpy as np

from solver.simulate.orbit import EarthModel, Orbit, acceleration_ecef

CONSISTENCY_TOL_M = 1.0  # Hermite residual of one interval above which it is inconsistent (good data: < 0.42 m)
EARTH = EarthModel()  # WGS 84 with the zonal terms J2-J4


def hermite_residuals(times_s: np.ndarray, positions_m: np.ndarray, velocities_m_s: np.ndarray) -> np.ndarray:
    """Residual (m) of each interval between neighbouring samples (module docstring), (n - 1,)."""
    a = acceleration_ecef(EARTH, positions_m, velocities_m_s)
    dt = np.diff(times_s)[:, None]
    pred = dt / 2 * (velocities_m_s[1:] + velocities_m_s[:-1]) + dt**2 / 12 * (a[:-1] - a[1:])
    return np.linalg.norm(np.diff(positions_m, axis=0) - pred, axis=1)


@dataclass
class EphemerisScreen:
    """What the screening kept and why it dropped the others."""

    kept: np.ndarray  # (n,) bool: samples used
    warnings: list[str] = field(default_factory=list)
    dropped_duplicates: list[int] = field(default_factory=list)  # 0-based sample indices
    dropped_inconsistent: list[int] = field(default_factory=list)
    residuals_m: np.ndarray = field(default_factory=lambda: np.zeros(0))


def label(epoch: datetime, t: float) -> str:
    """The UTC instant ``t`` seconds after ``epoch``, ISO 8601 to the millisecond."""
    return (epoch + timedelta(seconds=float(t))).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def screen(times_s: np.ndarray, positions_m: np.ndarray, velocities_m_s: np.ndarray, epoch: datetime,
           what: str = "ephemeris", tol_m: float = CONSISTENCY_TOL_M) -> EphemerisScreen:
    """Duplicated samples (same time) and states inconsistent with their neighbours. A sample
    repeating an earlier time is dropped (warned; its values are compared with the first); of the
    rest, the longest run of consistent intervals is kept and every other sample named in a
    warning. Times must otherwise increase (the caller refuses them when not)."""
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
    res = hermite_residuals(times_s[idx], positions_m[idx], velocities_m_s[idx])
    out.residuals_m = res
    good = res <= tol_m
    best_start, best_len, start = 0, 0, None
    for i, g in enumerate(np.append(good, False)):
        if g and start is None:
            start = i
        elif not g and start is not None:
            if i - start > best_len:
                best_start, best_len = start, i - start
            start = None
    if best_len == 0 and idx.size > 1:
        keep_idx = idx[:0]
    else:
        keep_idx = idx[best_start:best_start + best_len + 1]
    bad = np.setdiff1d(idx, keep_idx)
    if bad.size:
        kept[bad] = False
        out.dropped_inconsistent = [int(b) for b in bad]
        worst = float(res[~good].max()) if np.any(~good) else 0.0
        first_bad = float(res[~good][0]) if np.any(~good) else 0.0
        out.warnings.append(
            f"{what}: {bad.size} states ({_ranges(bad)}, {label(epoch, times_s[bad[0]])} to "
            f"{label(epoch, times_s[bad[-1]])}) disagree with the velocities of their neighbours "
            f"({first_bad:.1f} m at the first inconsistent interval, {worst:.1f} m at the worst; "
            f"good states agree to {tol_m:g} m): not used")
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
