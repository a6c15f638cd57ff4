"""Statistical tests of an adjustment (seed 000 Tables 4, 6, 8, 10; seed 001 Shapiro-Wilk).

* Global test of the variance factor: ``chi2 = v^T P v / sigma0_apriori^2`` with ``dof``
  degrees of freedom, accepted when it lies between the alpha/2 and 1 - alpha/2 quantiles
  (seed 000 compares it with chi2(dof; 0.975), the upper bound for alpha = 0.05).
* Bias of check-point discrepancies per axis: Student's t = mean sqrt(n) / s (seed 000 eq 24),
  two-sided at alpha with n - 1 degrees of freedom.
* Normality of the discrepancies per axis: Shapiro-Wilk (needs n >= 3).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from solver.quality import distributions


def chi2_test(weighted_ssr: float, dof: int, alpha: float, sigma0_apriori: float = 1.0) -> dict[str, Any] | None:
    if dof <= 0:
        return None
    statistic = weighted_ssr / sigma0_apriori**2
    upper = distributions.chi2_upper_quantile(alpha / 2.0, dof)
    lower = distributions.chi2_quantile(alpha / 2.0, dof)
    return {
        "statistic": float(statistic),
        "dof": int(dof),
        "critical": upper,
        "critical_lower": lower,
        "alpha": alpha,
        "passed": bool(lower <= statistic <= upper),
    }


def t_test(values: np.ndarray, alpha: float) -> dict[str, Any] | None:
    values = np.asarray(values, dtype=float)
    n = len(values)
    if n < 2:
        return None
    s = float(np.std(values, ddof=1))
    mean = float(np.mean(values))
    statistic = mean * math.sqrt(n) / s if s > 0 else (0.0 if mean == 0 else math.inf)
    critical = distributions.t_quantile(1.0 - alpha / 2.0, n - 1)
    return {
        "statistic": float(statistic),
        "critical": critical,
        "dof": n - 1,
        "alpha": alpha,
        "passed": bool(abs(statistic) <= critical),
    }


def shapiro_wilk(values: np.ndarray, alpha: float) -> dict[str, Any] | None:
    values = np.asarray(values, dtype=float)
    if len(values) < 3 or np.ptp(values) == 0:
        return None
    w, p = distributions.shapiro_wilk(values)
    return {"statistic": float(w), "p_value": float(p), "alpha": alpha, "passed": bool(p > alpha)}


def axis_summary(values: dict[str, np.ndarray]) -> tuple[dict, dict, dict]:
    """mean, std (n - 1), rmse per axis (None where an axis has no values)."""
    mean, std, rmse = {}, {}, {}
    for k, v in values.items():
        v = np.asarray(v, dtype=float)
        if len(v) == 0:
            mean[k] = std[k] = rmse[k] = None
            continue
        mean[k] = float(np.mean(v))
        std[k] = float(np.std(v, ddof=1)) if len(v) > 1 else None
        rmse[k] = float(np.sqrt(np.mean(v**2)))
    return mean, std, rmse
