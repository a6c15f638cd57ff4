"""The test distributions' quantiles and the Shapiro-Wilk normality test, on ``scipy.special``.

Why not ``scipy.stats``: importing it (with ``scipy.optimize`` and the rest it pulls in) takes
about half a second, paid once by every new process that writes a report (a command-line run, a
worker's first job). The special functions below are the ones ``scipy.stats`` itself evaluates
(cdflib and Cephes); tests/solver/quality/test_distributions.py compares every function here with
``scipy.stats`` over the ranges the reports use.

Shapiro-Wilk follows Royston (1995), "Remark AS R94", Applied Statistics 44(4): 547-551 (the
algorithm behind ``scipy.stats.shapiro``): the coefficients from the normal scores
``m_i = Phi^-1((i - 3/8) / (n + 1/4))`` with Royston's polynomial corrections for the two
outermost ones, and the p-value from his normalising transformations of ``W`` (exact for n = 3,
one for 4 <= n <= 11, one for n >= 12). The normal scores here are exact (``ndtri``) where AS R94
uses a 7-digit approximation (AS 241 PPND7), so W and p agree with ``scipy.stats.shapiro`` to
about 1e-6, not to the last bit.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special


def chi2_quantile(p: float, dof: float) -> float:
    """x with P(chi-square(dof) <= x) = p."""
    return 2.0 * float(special.gammaincinv(dof / 2.0, p))


def chi2_upper_quantile(alpha: float, dof: float) -> float:
    """x with P(chi-square(dof) > x) = alpha (without the rounding of 1 - alpha for tiny alpha)."""
    return 2.0 * float(special.gammainccinv(dof / 2.0, alpha))


def f_quantile(p: float, dof1: float, dof2: float) -> float:
    """x with P(F(dof1, dof2) <= x) = p."""
    return float(special.fdtri(dof1, dof2, p))


def t_quantile(p: float, dof: float) -> float:
    """x with P(Student-t(dof) <= x) = p."""
    return float(special.stdtrit(dof, p))


def normal_quantile(p: float) -> float:
    """x with P(N(0, 1) <= x) = p."""
    return float(special.ndtri(p))


def beta_quantile(p: float, a: float, b: float) -> float:
    """x with P(Beta(a, b) <= x) = p."""
    return float(special.betaincinv(a, b, p))


def chi2_noncentrality(x: float, dof: float, sf: float) -> float:
    """lambda with P(chi-square(dof, lambda) > x) = sf (the non-central chi-square's survival
    function at ``x`` inverted for its non-centrality)."""
    return float(special.chndtrinc(x, dof, 1.0 - sf))


# Royston (1995) polynomials in u = 1/sqrt(n) for the outermost coefficients, and in n or ln n
# for the mean and log standard deviation of the normalised W (constant term first).
_A_N = (0.0, 0.221157, -0.147981, -2.071190, 4.434685, -2.706056)
_A_N1 = (0.0, 0.042981, -0.293762, -1.752461, 5.682633, -3.582633)
_GAMMA_SMALL = (-2.273, 0.459)
_MEAN_SMALL = (0.5440, -0.39978, 0.025054, -6.714e-4)
_LOGSD_SMALL = (1.3822, -0.77857, 0.062767, -0.0020322)
_MEAN_LARGE = (-1.5861, -0.31082, -0.083751, 0.0038915)
_LOGSD_LARGE = (-0.4803, -0.082676, 0.0030302)


def _poly(c: tuple[float, ...], x: float) -> float:
    return sum(ci * x**i for i, ci in enumerate(c))


def shapiro_wilk_coefficients(n: int) -> np.ndarray:
    """The n weights a (antisymmetric, unit norm) of W = (a . x_sorted)^2 / sum (x - mean)^2."""
    if n < 3:
        raise ValueError("Shapiro-Wilk needs at least 3 values")
    if n == 3:
        return np.array([-math.sqrt(0.5), 0.0, math.sqrt(0.5)])
    m = special.ndtri((np.arange(1, n + 1) - 0.375) / (n + 0.25))
    mm = float(m @ m)
    u = 1.0 / math.sqrt(n)
    a = np.empty(n)
    a_n = m[-1] / math.sqrt(mm) + _poly(_A_N, u)
    if n > 5:
        a_n1 = m[-2] / math.sqrt(mm) + _poly(_A_N1, u)
        phi = (mm - 2.0 * m[-1] ** 2 - 2.0 * m[-2] ** 2) / (1.0 - 2.0 * a_n**2 - 2.0 * a_n1**2)
        a[2:-2] = m[2:-2] / math.sqrt(phi)
        a[-2], a[1] = a_n1, -a_n1
    else:
        phi = (mm - 2.0 * m[-1] ** 2) / (1.0 - 2.0 * a_n**2)
        a[1:-1] = m[1:-1] / math.sqrt(phi)
    a[-1], a[0] = a_n, -a_n
    return a


def shapiro_wilk(values: np.ndarray) -> tuple[float, float]:
    """(W, p-value) of the Shapiro-Wilk test that ``values`` (at least 3, not all equal) come from
    a normal distribution; a small p rejects normality."""
    x = np.sort(np.asarray(values, dtype=float))
    n = len(x)
    a = shapiro_wilk_coefficients(n)
    centred = x - x.mean()
    ss = float(centred @ centred)
    if not ss > 0.0:
        raise ValueError("Shapiro-Wilk needs values that are not all equal")
    w = min(float(a @ centred) ** 2 / ss, 1.0)
    if n == 3:
        w = max(w, 0.75)
        p = 6.0 / math.pi * (math.asin(math.sqrt(w)) - math.asin(math.sqrt(0.75)))
        return w, min(max(p, 0.0), 1.0)
    log_1mw = math.log1p(-w) if w < 1.0 else -math.inf
    if n <= 11:
        gamma = _poly(_GAMMA_SMALL, n)
        if log_1mw >= gamma:  # beyond the transformation's range: W far below normal samples'
            return w, 0.0
        y = -math.log(gamma - log_1mw)
        z = (y - _poly(_MEAN_SMALL, n)) / math.exp(_poly(_LOGSD_SMALL, n))
    else:
        ln_n = math.log(n)
        z = (log_1mw - _poly(_MEAN_LARGE, ln_n)) / math.exp(_poly(_LOGSD_LARGE, ln_n))
    return w, float(special.ndtr(-z))
