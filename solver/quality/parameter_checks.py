"""Checks of the estimated parameters: warnings on implausible platform parameters and on
correlated pairs, and the F test of a constraint that the significance analyses use.

Warnings (always, from the covariance of the solution):

* an attitude angle (orbit-attitude and pass models) whose standard deviation over the image exceeds the plausible limit
  (``options.quality_warnings.attitude_sigma_deg``, default 0.1 deg): a constant term by its
  own sigma, a rate term ``k`` by its sigma times (half the image duration)^k (the change of
  the angle it can cause between the centre and an end of the image);
* a pair of platform, pass or interior-orientation parameters correlated beyond
  ``correlation`` (default 0.99) in magnitude: nearly undetermined together.

Significance analysis (``options.parsimony``): :func:`solver.procedures.parsimony.parsimony_analysis`
(it re-adjusts, so it is a procedure) uses :func:`constraint_test` from here.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from solver.quality.distributions import f_quantile
from solver.state import AdjustmentState

# models whose angles are the platform's attitude relative to the orbital frame (orbit-attitude,
# pass): there an angle is physical and a sigma of degrees is implausible. The angles of the
# position-rotation models (polynomial, Kepler) absorb the position's errors (pitch against
# along-track position) and carry large sigmas legitimately when the state is free.
ORBITAL_FRAME_ANGLES = ("roll", "pitch", "yaw")


def _angle_reach(unit: str, duration_s: float, lines: int) -> float | None:
    """Factor turning the sigma of a parameter of ``unit`` into the sigma of the angle change
    it can cause over half the image (deg); None for a parameter that is not an attitude angle."""
    if unit == "deg":
        return 1.0
    if unit.startswith("deg/s"):
        k = int(unit.split("^")[1]) if "^" in unit else 1
        return (duration_s / 2.0) ** k
    if unit.startswith("deg/line"):
        k = int(unit.split("^")[1]) if "^" in unit else 1
        return (lines / 2.0) ** k
    return None


def implausible_sigmas(problem: AdjustmentState, images_report: list[dict[str, Any]], limit_deg: float) -> list[dict[str, Any]]:
    """Attitude parameters whose sigma, as an angle over the image, exceeds ``limit_deg``."""
    out = []
    for img, rep in zip(problem.images, images_report):
        if img.camera is None or img.model.angle_names != ORBITAL_FRAME_ANGLES:
            continue
        cam = img.camera
        lines = cam.lines or 0
        duration = lines * (cam.line_time_s or 0.0)
        for p in rep["parameters"]:
            if not p["estimated"] or p["sigma"] is None:
                continue
            reach = _angle_reach(p["unit"], duration, lines)
            if reach is None:
                continue
            angle_sigma = p["sigma"] * reach
            if angle_sigma > limit_deg:
                out.append(
                    {
                        "kind": "implausible_sigma",
                        "image": img.id,
                        "parameter": p["name"],
                        "value": p["value"],
                        "sigma": p["sigma"],
                        "unit": p["unit"],
                        "angle_sigma_deg": angle_sigma,
                        "limit_deg": limit_deg,
                        "message": (
                            f"image {img.id!r}: {p['name']} = {p['value']:.4g} {p['unit']} with sigma "
                            f"{p['sigma']:.3g} {p['unit']} ({angle_sigma:.3g} deg over the image, beyond "
                            f"the plausible {limit_deg:g} deg): the control does not determine it; use a "
                            "lower attitude order, weight the attitude or add control"
                        ),
                    }
                )
    return out


CORRELATION_STRIP = 256
"""Rows of the images' covariance turned into correlation coefficients at a time by
:func:`correlated_pairs`: a 1,500-image block's 21,000-square covariance is 3.5 GB, and its whole
correlation matrix with the indices of its upper triangle was four times that."""


def correlated_pairs(cov_images: np.ndarray, limit: float, inclusive: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The parameter pairs (i < j) whose correlation coefficient rho = Q_ij / sqrt(Q_ii Q_jj),
    clipped to [-1, 1], has |rho| > ``limit`` (``>=`` with ``inclusive``): (i, j, rho), in
    row-major order of the upper triangle. Computed in row strips of
    :data:`CORRELATION_STRIP`, so the memory beyond ``cov_images`` is a strip, not a matrix."""
    n = cov_images.shape[0]
    d = np.sqrt(np.clip(np.diag(cov_images), 1e-300, None))
    found_i, found_j, found_rho = [], [], []
    for k in range(0, n, CORRELATION_STRIP):
        e = min(k + CORRELATION_STRIP, n)
        rho = np.clip(cov_images[k:e, k + 1 :] / np.outer(d[k:e], d[k + 1 :]), -1.0, 1.0)
        above = np.abs(rho) >= limit if inclusive else np.abs(rho) > limit
        # only the upper triangle: column k + 1 + c belongs to row k + r when c >= r
        above &= np.arange(rho.shape[1])[None, :] >= np.arange(e - k)[:, None]
        r, c = np.nonzero(above)
        found_i.append(k + r)
        found_j.append(k + 1 + c)
        found_rho.append(rho[r, c])
    if not found_i:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
    return np.concatenate(found_i), np.concatenate(found_j), np.concatenate(found_rho)


def high_correlations(cov_images: np.ndarray | None, names: list[str], limit: float, max_pairs: int = 50) -> list[dict[str, Any]]:
    """Pairs of orientation parameters with |rho| > ``limit`` (strongest first, at most ``max_pairs``)."""
    if cov_images is None or cov_images.size == 0:
        return []
    ii, jj, vals = correlated_pairs(cov_images, limit)
    big = np.argsort(-np.abs(vals))[:max_pairs]
    return [
        {
            "kind": "high_correlation",
            "a": names[ii[k]],
            "b": names[jj[k]],
            "rho": float(vals[k]),
            "limit": limit,
            "message": (
                f"{names[ii[k]]} and {names[jj[k]]} are correlated {vals[k]:+.4f} (beyond {limit:g}): "
                "the data hardly separate them; hold, drop or weight one of them"
            ),
        }
        for k in big
    ]


def constraint_test(delta_vtpv: float, q: int, vtpv: float, dof: int, alpha: float) -> dict[str, Any]:
    """Test of the hypothesis that ``q`` parameters are zero, from the increase of the weighted
    sum of squares when they are held: ``F = (dvtpv / q) / (vtpv / dof)``, accepted (the
    constraint is compatible with the data, the terms can go) below the ``1 - alpha`` quantile
    of F(q, dof). The report's entry (:func:`constraint_decision` gives it with its decision)."""
    return constraint_decision(delta_vtpv, q, vtpv, dof, alpha)[0]


def constraint_decision(delta_vtpv: float, q: int, vtpv: float, dof: int, alpha: float) -> tuple[dict[str, Any], bool]:
    """:func:`constraint_test`'s entry and whether the constraint is accepted."""
    f = (max(delta_vtpv, 0.0) / q) / (vtpv / dof) if dof > 0 and vtpv > 0 else math.inf
    crit = f_quantile(1.0 - alpha, q, dof) if dof > 0 else math.inf
    passed = bool(f <= crit)
    return {"statistic": float(f), "dof": [q, dof], "critical": crit, "alpha": alpha, "passed": passed}, passed
