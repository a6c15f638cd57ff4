"""The screening every reader applies to the exact model it built, before anything uses it:

- **ephemeris** (:func:`solver.sensors.ephemeris_check.screen`): the frame of the velocities
  (inertial ones converted to Earth-fixed, with a note), duplicated samples, gaps, and states
  whose positions disagree with their velocities (dropped, named);
- **attitude**: duplicated sample times (the later sample dropped) and samples that break the
  attitude's continuity: a sample whose rotation departs from the slerp of its two neighbours
  by more than :data:`ATTITUDE_JUMP_RAD` and :data:`ATTITUDE_JUMP_FACTOR` times the median
  departure is dropped (the worst first, then again). On the public files the departures are
  below 4e-6 rad (Maxar's 50 Hz quaternions, rounded to 1e-9) and 4e-7 rad (SPOT's 8 Hz
  angles); a flipped or corrupted sample departs by tenths of a radian. Quaternion norms are
  checked by the readers, which refuse a file whose quaternions are not unit ones (1e-3);
- **time scale**: samples spanning a leap second of :mod:`solver.sensors.timescales` are
  refused (every time of these files is UTC, and Python's datetimes have no 23:59:60);
- **coverage**: what is kept must still cover the image's lines.

What was dropped or converted is in :class:`Screening` (``warnings``, ``notes``): printed by
``pba import-sensor`` and ``pba check-sensor`` and carried in the job (``images[].sensor``) into
the report.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta

import numpy as np

from solver.sensors.ephemeris_check import EARTH_FIXED, label, screen
from solver.sensors.linescan import LinescanModel
from solver.sensors.timescales import UnknownLeapSeconds, leap_seconds_between
from solver.sensors.xmlsafe import Node

ATTITUDE_JUMP_RAD = 2e-5  # a sample departing from its neighbours' slerp by more than this ...
ATTITUDE_JUMP_FACTOR = 50.0  # ... and this many times the median departure breaks the continuity
MIN_STATES = 4  # ephemeris states needed after the screening
COVER_INTERVALS = 2.0  # the kept samples may end this many sample intervals inside the image's first/last line


@dataclass
class Screening:
    """What the screening of one product did (module docstring)."""

    notes: list[str] = field(default_factory=list)  # conversions: said, not faults
    warnings: list[str] = field(default_factory=list)  # samples dropped, gaps
    velocity_frame: str = EARTH_FIXED  # the frame the file's velocities were found in
    velocity_rms_m_s: float | None = None  # how well the kept velocities agree with the positions (m/s)
    dropped_states: list[int] = field(default_factory=list)  # 0-based ephemeris samples not used
    dropped_attitude: list[int] = field(default_factory=list)  # 0-based attitude samples not used

    def messages(self) -> list[str]:
        return self.notes + self.warnings


def slerp_departures(times_s: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """Angle (rad) between each interior sample's rotation and the slerp of its two neighbours
    at its time, (n - 2,)."""
    q0, q1, qk = q_wxyz[:-2], q_wxyz[2:].copy(), q_wxyz[1:-1]
    dot = np.sum(q0 * q1, axis=1)
    q1[dot < 0] *= -1
    theta = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))[:, None]
    u = ((times_s[1:-1] - times_s[:-2]) / (times_s[2:] - times_s[:-2]))[:, None]
    small = theta < 1e-12
    s = np.where(small, 1.0, np.sin(theta))
    a = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / s)
    b = np.where(small, u, np.sin(u * theta) / s)
    p = a * q0 + b * q1
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(p * qk, axis=1)), 0.0, 1.0))


def attitude_outliers(times_s: np.ndarray, q_wxyz: np.ndarray, max_drops: int = 20) -> list[int]:
    """0-based samples that break the attitude's continuity (module docstring), worst first."""
    keep = np.ones(times_s.size, bool)
    out: list[int] = []
    while len(out) < max_drops and keep.sum() >= 3:
        idx = np.flatnonzero(keep)
        d = slerp_departures(times_s[idx], q_wxyz[idx])
        limit = max(ATTITUDE_JUMP_RAD, ATTITUDE_JUMP_FACTOR * float(np.median(d)))
        k = int(np.argmax(d))
        if d[k] <= limit:
            break
        # a jump at sample j also moves its neighbours' departures (by about half): drop the worst alone
        out.append(int(idx[k + 1]))
        keep[idx[k + 1]] = False
    return out


def _duplicate_times(times_s: np.ndarray) -> list[int]:
    """0-based samples repeating the time of an earlier one."""
    _, first = np.unique(times_s, return_index=True)
    return sorted(set(range(times_s.size)) - set(first.tolist()))


def screen_model(model: LinescanModel, eph: Node, att: Node) -> tuple[LinescanModel, Screening]:
    """``model`` with its ephemeris and attitude screened (module docstring), and what was done;
    a located error (the ephemeris node ``eph``, the attitude node ``att``) when too little is left."""
    epoch = datetime.fromisoformat(model.epoch_utc.replace("Z", "+00:00"))
    t_e, t_a = model.ephemeris_times_s, model.attitude_times_s
    span = (min(t_e[0], t_a[0]), max(t_e[-1], t_a[-1]))
    try:
        leaps = leap_seconds_between(epoch + timedelta(seconds=float(span[0])), epoch + timedelta(seconds=float(span[1])))
    except UnknownLeapSeconds as exc:
        raise eph.error(f"{exc}: not read") from None
    if leaps:
        raise eph.error(f"the samples span the leap second before {leaps[0].isoformat()}: not read")

    checked = screen(t_e, model.positions_ecef_m, model.velocities_ecef_m_s, epoch, eph.path)
    out = Screening(list(checked.notes), list(checked.warnings), checked.velocity_frame, checked.velocity_rms_m_s,
                    sorted(checked.dropped_duplicates + checked.dropped_inconsistent))
    kept_e = checked.kept
    if kept_e.sum() < MIN_STATES:
        raise eph.error(f"only {int(kept_e.sum())} consistent ephemeris states: " + "; ".join(out.warnings))

    dup = _duplicate_times(t_a)
    for k in dup:
        out.warnings.append(f"{att.path}: sample {k + 1} repeats the time {label(epoch, t_a[k])} of an earlier one: dropped")
    keep_a = np.ones(t_a.size, bool)
    keep_a[dup] = False
    idx = np.flatnonzero(keep_a)
    jumps = [int(idx[j]) for j in attitude_outliers(t_a[idx], model.attitude_wxyz[idx])]
    if jumps:
        keep_a[jumps] = False
        d = slerp_departures(t_a[idx], model.attitude_wxyz[idx])
        out.warnings.append(f"{att.path}: {len(jumps)} samples ({', '.join(str(j + 1) for j in sorted(jumps))}, "
                            f"{label(epoch, t_a[min(jumps)])} first) depart from their neighbours by up to "
                            f"{float(d.max()):.3g} rad (the others by {float(np.median(d)):.2g} rad): not used")
    out.dropped_attitude = sorted(dup + jumps)
    if keep_a.sum() < 2:
        raise att.error(f"only {int(keep_a.sum())} usable attitude samples: " + "; ".join(out.warnings))

    screened = replace(
        model, ephemeris_times_s=t_e[kept_e], positions_ecef_m=model.positions_ecef_m[kept_e],
        velocities_ecef_m_s=checked.velocities_m_s[kept_e], attitude_times_s=t_a[keep_a],
        attitude_wxyz=model.attitude_wxyz[keep_a],
    )
    lines = np.array([0.0, model.lines - 1.0])
    t_img = screened.line_time(lines)
    for node, t in ((eph, screened.ephemeris_times_s), (att, screened.attitude_times_s)):
        margin = COVER_INTERVALS * float(np.median(np.diff(t)))
        if (out.dropped_states or out.dropped_attitude) and (t_img.min() < t[0] - margin or t_img.max() > t[-1] + margin):
            raise node.error("after the screening the samples left do not cover the image's lines: "
                             + "; ".join(out.warnings))
    return screened, out
