"""Data snooping: one test per observation group, the separability of the tests, the
estimated errors, and the ``quality`` report section (docs/quality.md).

For a group g (d rows) with whitened residuals v_g and residual cofactor Q_gg
(:mod:`solver.quality.reliability`), the test statistic of the alternative "g has an error"
is ``T = v_g^T Q_gg^+ v_g`` (rank d' of Q_gg; d' = 1: T = w^2 with Baarda's w).

* sigma0 a priori known (``variance: apriori``, Baarda): ``T / sigma0^2 ~ chi2(d')``; the report's
  ``w`` is ``sqrt(T) / sigma0`` and its ``critical`` value ``sqrt(chi2_{1-alpha0}(d'))``
  (3.29 for d' = 1, alpha0 = 0.001).
* sigma0 estimated (``variance: estimated``, Pope): with Omega = v^T v over all r degrees of
  freedom, ``T / Omega ~ Beta(d'/2, (r - d')/2)``; ``w`` is tau = sqrt(T / s^2) with
  s^2 = Omega / r and ``critical`` = sqrt(r Beta_{1-alpha0}(d'/2, (r - d')/2)).

The estimated error of g (whitened) is ``Q_gg^+ v_g`` times the sign relating the residual
to the observation (image points and lines: observed - model; priors: model - observed).
Another group h of the same block cannot be told apart from g when its test sees the same
residual pattern: the correlation of the 1-D test along g's estimated error direction e with
h's test, ``rho^2 = e^T Q_gh Q_hh^+ Q_hg e / e^T Q_gg e``, reaches ``separability``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.engine.linalg import linearise, positive_definite_inverse, schur
from solver.quality.distributions import beta_quantile, chi2_upper_quantile, f_quantile, normal_quantile
from solver.quality.reliability import (
    REDUNDANCY_NEAR_ZERO,
    Group,
    Structure,
    bias_effect,
    bias_to_noise,
    group_cofactor,
    minimal_detectable_bias,
    noncentrality,
    redundancy,
    structure,
    weakest_direction,
)
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState

EIGEN_TOL = REDUNDANCY_NEAR_ZERO  # eigenvalues of Q_gg below this (redundancy ~0) carry no test


@dataclass
class Test:
    group: Group
    statistic: float  # T (whitened, sigma0 = 1)
    dof: int  # rank of Q_gg
    w: float | None  # sqrt(T)/sigma0 (Baarda) or tau (Pope)
    critical: float | None
    error_whitened: np.ndarray  # estimated error, whitened
    error: list[float]  # estimated error, observation units

    @property
    def failed(self) -> bool:
        return self.w is not None and self.critical is not None and self.w > self.critical


@dataclass
class Snoop:
    """The tests of one adjustment."""

    structure: Structure
    tests: list[Test]
    residuals: np.ndarray
    dof: int
    vtpv: float
    variance: str
    alpha0: float
    beta: float
    s0_apriori: float = 1.0
    lambda0: dict[int, float] = field(default_factory=dict)

    def lam0(self, dim: int) -> float:
        if dim not in self.lambda0:
            self.lambda0[dim] = noncentrality(self.alpha0, self.beta, dim)
        return self.lambda0[dim]


@dataclass
class FixedControlGroup(Group):
    """A fixed control point (``control: fixed``) seen in its rays: the alternative "its known
    coordinates are wrong by delta" biases all its rays by ``C delta`` (C: the whitened ray
    Jacobian wrt the point, per LGS metre). The test lives in the column space of C, with the
    orthonormal basis ``basis`` (rows x k, k = rank C: 3, or 2 for a point seen in one image),
    and ``to_metres`` maps an estimate in that basis to metres (V S^-1)."""

    basis: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    to_metres: np.ndarray = field(default_factory=lambda: np.zeros((3, 0)))


def _basis(g: Group) -> np.ndarray | None:
    return g.basis if isinstance(g, FixedControlGroup) else None


def _fixed_control_groups(problem: AdjustmentState, lin, st: Structure) -> None:
    """Add a test group for each fixed control point (its rays' block has no point columns)."""
    from solver.engine.packed_tables import current_tables, records
    from solver.kernels import all_observation_blocks

    blocks = [
        (b, blk) for b, blk in enumerate(st.blocks)
        if blk.jp is None and blk.point >= 0 and problem.points[blk.point].role == "gcp" and not problem.points[blk.point].estimated
    ]
    if not blocks:
        return
    lay = lin.layout
    img_tab, cam_tab, img_p, cam_p = current_tables(problem)
    pts = np.ascontiguousarray(np.array([p.xyz for p in problem.points], dtype=float).reshape(-1, 3))
    every = np.ones(len(problem.points), dtype=np.bool_)
    jpt = all_observation_blocks(
        records(problem, lin.obs_sel), img_tab, cam_tab, img_p, cam_p, pts, np.ascontiguousarray(lin.obs_pt), every,
        lay.img_col, lay.cam_col, lay.pass_col, lin.jf.shape[2],
    )[3]
    for b, blk in blocks:
        idx = blk.rows[0::2] // 2  # the block's observations (rows 2i, 2i + 1)
        c = jpt[idx].reshape(-1, 3)
        u, sv, vt = np.linalg.svd(c, full_matrices=False)
        keep = sv > 1e-9 * sv.max()
        point = problem.points[blk.point]
        st.groups.append(
            FixedControlGroup(
                "control_point", {"point": point.id, "fixed": True}, b, np.arange(len(blk.rows)), np.ones(3), "m",
                ["e", "n", "u"], ("control", blk.point), -1.0, basis=u[:, keep], to_metres=vt[keep].T / sv[keep],
            )
        )


def _pinv(q: np.ndarray) -> tuple[np.ndarray, int]:
    e, v = np.linalg.eigh(q)
    keep = e > EIGEN_TOL
    return (v[:, keep] / e[keep]) @ v[:, keep].T, int(keep.sum())


def _critical(variance: str, alpha0: float, dim: int, dof: int) -> float | None:
    if variance == "apriori":
        return math.sqrt(chi2_upper_quantile(alpha0, dim))
    if dof - dim <= 0:
        return None
    return math.sqrt(dof * beta_quantile(1.0 - alpha0, dim / 2.0, (dof - dim) / 2.0))


def snoop(problem: AdjustmentState, options, robust: bool = False, linearised: Any = None) -> Snoop:
    """Every group's test at the current parameters of ``problem`` (``options``: the job's
    ``options.blunder_detection``). ``robust``: the parameters come from a robust adjustment;
    sigma0 is then the a-priori one, or with ``variance: estimated`` the robust estimate
    1.4826 median |v_i / sqrt(r_i)| over the rows with redundancy (Baarda's test either way).
    ``linearised``: the report's linearisation at these parameters
    (:class:`solver.report.document.Linearised`: the Jacobians, the eliminated points, the
    inverse of the reduced matrix), used instead of linearising and inverting again."""
    if linearised is not None:
        lin, parts, s_inv = linearised.lin, linearised.parts, linearised.s_inv
    else:
        lin = linearise(problem)
        parts = schur(lin, problem)
        s_inv = positive_definite_inverse(parts.s)  # LinAlgError: no tests without a covariance
    st = structure(problem, lin, parts, s_inv)
    _fixed_control_groups(problem, lin, st)
    res = lin.residuals
    dof = len(res) - lin.layout.n_params
    vtpv = float(res @ res)
    s0_apriori = JobSettings.of(problem.job).statistics.sigma0_apriori
    out = Snoop(st, [], res, dof, vtpv, options.variance, options.alpha0, options.beta, s0_apriori)
    robust_scale = None
    if robust:
        robust_scale = s0_apriori
        if options.variance == "estimated":
            std = [
                res[st.blocks[g.block].rows[g.local]] / np.sqrt(np.maximum(np.diag(group_cofactor(st, g)), 1e-12))
                for g in st.groups
                if not isinstance(g, FixedControlGroup)
            ]
            std = np.concatenate(std) if std else np.zeros(0)
            if len(std):
                robust_scale = float(1.4826 * np.median(np.abs(std)))
    for g in st.groups:
        blk = st.blocks[g.block]
        v = res[blk.rows[g.local]]
        basis = _basis(g)
        if basis is not None:
            v = basis.T @ v
        q_inv, d = _pinv(_cofactor(st, g))
        err_w = g.sign * (q_inv @ v)
        t_stat = float(v @ q_inv @ v)
        w = crit = None
        if d > 0:
            if robust_scale is not None:
                w, crit = math.sqrt(t_stat) / robust_scale, _critical("apriori", options.alpha0, d, dof)
            elif options.variance == "apriori":
                w, crit = math.sqrt(t_stat) / s0_apriori, _critical("apriori", options.alpha0, d, dof)
            elif dof > 0 and vtpv > 0:
                w, crit = math.sqrt(t_stat / (vtpv / dof)), _critical("estimated", options.alpha0, d, dof)
        if basis is not None:  # the error of the known coordinates, LGS metres
            err_w = q_inv @ v
            error = [float(x) for x in g.to_metres @ err_w]
        else:
            error = [float(x) for x in err_w * g.sigma]
        out.tests.append(Test(g, t_stat, d, w, crit, err_w, error))
    return out


def _cofactor(st: Structure, g: Group) -> np.ndarray:
    """Q_gg in the group's test space (a fixed control point: its basis of C)."""
    q = group_cofactor(st, g)
    b = _basis(g)
    return q if b is None else b.T @ q @ b


def cross_cofactor(st: Structure, g: Group, h: Group) -> np.ndarray:
    """Q_gh between two groups: the block's own entries, or across blocks (rows sharing only
    image, camera or pass parameters) -U_g S^-1 U_h^T (in the test spaces of g and h)."""
    if g.block == h.block:
        q = st.blocks[g.block].q[np.ix_(g.local, h.local)]
    else:
        bg, bh = st.blocks[g.block], st.blocks[h.block]
        if not len(bg.cols) or not len(bh.cols):
            q = np.zeros((g.dim, h.dim))
        else:
            q = -(bg.u[g.local] @ st.s_inv[np.ix_(bg.cols, bh.cols)] @ bh.u[h.local].T)
    bg_, bh_ = _basis(g), _basis(h)
    if bg_ is not None:
        q = bg_.T @ q
    if bh_ is not None:
        q = q @ bh_
    return q


def _correlation(st: Structure, g: Group, h: Group, direction: np.ndarray) -> float:
    """The correlation of the 1-D test of g along ``direction`` (whitened) with h's test."""
    q_gh = cross_cofactor(st, g, h)
    q_hh_inv, d = _pinv(_cofactor(st, h))
    den = float(direction @ _cofactor(st, g) @ direction)
    if d == 0 or den <= 0:
        return 0.0
    x = q_gh.T @ direction
    return float(math.sqrt(max(x @ q_hh_inv @ x, 0.0) / den))


def inseparable(sn: Snoop, t: Test, threshold: float) -> list[Test]:
    """The tests that cannot be told apart from t for its estimated error (t first): all the
    tests of t's block, and the failed tests of other blocks (a test correlated with t to
    ``threshold`` >= 0.5 fails along with it when t's error is large enough to be rejected);
    also a failed test u of t's block (another ray of its point) of the same dimension,
    correlated with t (rho >= 0.5), whose value is not significantly below t's:
    ``w_t - w_u < z_{1-alpha0} sqrt(2 (1 - rho))``."""
    members = [t]
    nrm = float(np.linalg.norm(t.error_whitened))
    if nrm == 0:
        return members
    direction = t.error_whitened / nrm
    z = normal_quantile(1.0 - sn.alpha0)
    for u in sn.tests:
        if u is t or u.w is None or (u.group.block != t.group.block and not u.failed):
            continue
        rho = _correlation(sn.structure, t.group, u.group, direction)
        if rho >= threshold:
            members.append(u)
        elif (
            u.group.block == t.group.block
            and u.failed
            and u.dof == t.dof
            and rho >= 0.5
            and t.w - u.w < z * math.sqrt(2.0 * (1.0 - rho))
        ):
            # a posteriori: the data do not prefer t over u at alpha0 (the difference of two
            # unit-variance tests correlated rho has the variance 2 (1 - rho)); e.g. the three
            # rays of a tie point with a mostly along-track error, w 6.91 / 6.87 / 6.43, rho ~0.93
            members.append(u)
    return members


def worst(sn: Snoop, removable_only: bool = True) -> Test | None:
    """The failed test with the largest w / critical (removable ones when asked)."""
    failed = [t for t in sn.tests if t.failed and (t.group.removal is not None or not removable_only)]
    if not failed:
        return None
    return max(failed, key=lambda t: t.w / t.critical)


def entry(t: Test, removed: bool) -> dict[str, Any]:
    """A test as a ``quality.rejected`` entry (also the shape of ``not_identifiable`` members)."""
    out = {"kind": t.group.kind, "image": None, **{k: v for k, v in t.group.label.items() if k != "role"}}
    out.update(
        {
            "w": t.w,
            "critical": t.critical,
            "dof": t.dof,
            "estimated_error": t.error,
            "units": t.group.units,
            "components": t.group.components,
            "removed": removed,
        }
    )
    return out


def failing_clusters(sn: Snoop, threshold: float) -> list[list[Test]]:
    """All failed tests, worst first, each with the tests it cannot be separated from; a test
    already in an earlier cluster is not repeated."""
    seen: set[int] = set()
    out = []
    for t in sorted((t for t in sn.tests if t.failed), key=lambda t: -t.w / t.critical):
        if id(t) in seen:
            continue
        members = [m for m in inseparable(sn, t, threshold) if id(m) not in seen]
        seen.update(id(m) for m in members)
        out.append(members)
    return out


def reliability_section(sn: Snoop) -> dict[str, Any]:
    """``quality.reliability``: redundancy numbers, minimal detectable biases and their effects."""
    st = sn.structure
    items = []
    unchecked = []
    total = 0.0
    d_img = np.sqrt(np.clip(np.diag(st.s_inv), 1e-300, None))
    for t in sn.tests:
        g = t.group
        if isinstance(g, FixedControlGroup):
            continue  # its rows are its image points' (counted there); its test is in rejected
        r = redundancy(st, g)
        total += float(r.sum())
        lam0 = sn.lam0(max(t.dof, 1))
        mdb = minimal_detectable_bias(st, g, lam0)
        finite = [k for k, m in enumerate(mdb) if m is not None]
        effect_sigma = effect_point = None
        if finite:
            k = max(finite, key=lambda k: mdb[k])  # the least-checked component
            b = np.zeros(g.dim)
            b[k] = mdb[k] / g.sigma[k]
            dx_img, dx_pt = bias_effect(st, g, b)
            effect_sigma = float(np.max(np.abs(dx_img) / d_img)) if len(dx_img) else 0.0
            effect_point = None if dx_pt is None else [float(x) for x in dx_pt]
        item = {
            "kind": g.kind,
            "image": None,
            **{k: v for k, v in g.label.items() if k != "role"},
            "redundancy": [float(x) for x in r],
            "mdb": mdb,
            "mdb_max": weakest_direction(st, g, lam0),
            "units": g.units,
            "bias_to_noise": bias_to_noise(st, g, lam0),
            "effect_on_parameters_sigma": effect_sigma,
            "effect_on_point_m": effect_point,
        }
        items.append(item)
        if g.kind == "control_point" and (r <= REDUNDANCY_NEAR_ZERO).any():
            unchecked.append({"point": g.label["point"], "unchecked": [c for c, x in zip(g.components, r) if x <= REDUNDANCY_NEAR_ZERO]})
    return {
        "alpha0": sn.alpha0,
        "beta": sn.beta,
        "lambda0": {str(k): v for k, v in sorted(sn.lambda0.items())},
        "total_redundancy": total,
        "dof": sn.dof,
        "groups": items,
        "unchecked_control_points": unchecked,
    }


def predicted_decision(sn: Snoop, t: Test, inflate: float, s2: tuple[float, int] | None = None, whole: bool = False) -> tuple[dict[str, Any], bool]:
    """:func:`predicted_test` and whether the observation passes it (it may be reinstated)."""
    test = predicted_test(sn, t, inflate, s2, whole)
    return test, bool(test["passed"])


@dataclass
class CollateralEntry:
    """An observation removed with a rejected one (:func:`solver.quality.removal.remove`'s
    collateral) as a ``quality.rejected`` entry; ``image_point``: an image point of the core (its
    image and point), else a family's (a line image left with fewer than two points)."""

    entry: dict[str, Any]
    image_point: bool
    image: str | None
    point: str | None


def collateral_entries(collateral: list[dict[str, Any]]) -> list[CollateralEntry]:
    """The ``quality.rejected`` entries of ``collateral`` removals (no test of their own)."""
    out = []
    for c in collateral:
        if c.get("kind", "image_point") != "image_point":
            label = {k: v for k, v in c.items() if k not in ("units", "components")}
            e = {**label, "w": None, "critical": None, "dof": 0, "estimated_error": None, "units": c["units"],
                 "components": c["components"], "removed": True, "collateral": True}
            out.append(CollateralEntry(e, False, c.get("image"), c.get("point")))
            continue
        e = {"kind": "image_point", **c, "w": None, "critical": None, "dof": 0, "estimated_error": None,
             "units": "px", "components": ["line", "column"], "removed": True, "collateral": True}
        out.append(CollateralEntry(e, True, c["image"], c["point"]))
    return out


def predicted_test(sn: Snoop, t: Test, inflate: float, s2: tuple[float, int] | None = None, whole: bool = False) -> dict[str, Any]:
    """The test of an observation *outside* the adjustment, from its group ``t`` put back with
    its sigmas times ``inflate`` (``solver.quality.removal.with_candidates``): the predicted
    residual e = inflate v' (whitened by the true sigma) has the cofactor
    Q_e = I + inflate^2 (I - Q'_gg) = I + J Q_xx J^T, and T = e^T Q_e^-1 e ~ chi2(d)
    (Baarda: ``w = sqrt(T) / sigma0``); with ``s2 = (s^2, r)`` (sigma0 estimated: the
    a-posteriori variance of the adjustment without the observation and its degrees of freedom)
    T / (d s^2) ~ F(d, r).
    In linear theory this equals the w-test of the observation in the adjustment with it.

    ``whole``: every row of g's block is such a candidate (a point that only removed
    observations determine): the point is estimated from them alone (its part of the hat
    matrix, ``P = J_p C^-1 J_p^T``, does not depend on the common inflation) and the
    orientation comes from the rest: ``Q_e = I - P + inflate^2 U S^-1 U^T`` (g's rows), of rank
    d <= its rows (the test of g against the final orientation and the point's other removed
    observations)."""
    g = t.group
    blk = sn.structure.blocks[g.block]
    v = sn.residuals[blk.rows[g.local]]
    e = inflate * v
    if whole and blk.jp is not None:
        p_pt = blk.jp @ blk.c_inv @ blk.jp.T
        h_img = blk.u @ sn.structure.s_inv[np.ix_(blk.cols, blk.cols)] @ blk.u.T if len(blk.cols) else np.zeros_like(p_pt)
        q_full = np.eye(len(blk.rows)) - p_pt + inflate**2 * h_img
        q_inv, d = _pinv(q_full[np.ix_(g.local, g.local)])
        if d == 0:
            return {"w": None, "critical": None, "dof": 0, "estimated_error": None, "passed": False}
        t_stat = float(e @ q_inv @ e)
    else:
        q = group_cofactor(sn.structure, g)
        q_e = np.eye(g.dim) + inflate**2 * (np.eye(g.dim) - q)
        t_stat = float(e @ np.linalg.solve(q_e, e))
        d = g.dim
    if s2 is None:
        w, crit = math.sqrt(t_stat) / sn.s0_apriori, _critical("apriori", sn.alpha0, d, sn.dof)
    else:
        w = math.sqrt(t_stat / s2[0])
        crit = math.sqrt(d * f_quantile(1.0 - sn.alpha0, d, max(s2[1], 1)))
    err = g.sign * e * (g.sigma / inflate)
    return {"w": w, "critical": crit, "dof": d, "estimated_error": [float(x) for x in err], "passed": w <= crit}
