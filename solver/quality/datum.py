"""The datum explained before solving: what defines it, and which of its directions the job
leaves undetermined, in words.

The datum of a block is where the block sits as a whole: a common shift of all tie points in
east, north and height, a tilt of their heights, a rotation about the vertical and a scale.
Control points, weighted platform states with measured attitude, the RPCs' bias priors and
DEM heights define it; tie points alone do not. For each of these seven directions of the tie
points (a linear function f = g^T y of their LGS coordinates) its predicted standard deviation
follows from the normal matrix N = J^T J of the whitened observations (a-priori sigma0 = 1,
the parameters in their own units: the points in metres)::

    sigma_f^2 = g^T C^-1 g + u^T S^-1 u,   u = B C^-1 g

with N = [[A, B], [B^T, C]] (A the images' and cameras' parameters, C the points' 3 x 3
blocks) and S = A - B C^-1 B^T the reduced matrix the rank check factors
(:mod:`solver.engine.linalg`). A direction whose sigma exceeds ``options.datum.max_sigma_m``
(or that lies in the null space of S: infinite) is *not determined*; the analysis names it
("a common height shift of all tie points"), the image parameters that move with it
(largest covariance with it, relative to their own sigmas: "b: a0"), and the remedies.
A direction not determined at all (the null space) refuses the job before the solve (a 4xx
problem, exit 2); one whose sigma is only too large at the initial values is confirmed at the
solution (initial values far from the truth can make a determined direction look weak) and
refused there. With ``options.datum.undetermined = "report"`` the job is adjusted and the
report says so.

Independent of the sigmas, the analysis says what each image is tied by (its control points,
its priors, or only tie points: then its orientation comes from the other images).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.engine import dense_threads
from solver.engine.linalg import Linearisation, SchurParts, b_times
from solver.errors import Problem
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState

DIRECTIONS = (
    ("shift_east", "a common shift of all tie points east-west", "m"),
    ("shift_north", "a common shift of all tie points north-south", "m"),
    ("shift_height", "a common height shift of all tie points", "m"),
    ("tilt_east", "a tilt of the tie points' heights east-west (height difference across the block)", "m"),
    ("tilt_north", "a tilt of the tie points' heights north-south (height difference across the block)", "m"),
    ("rotation", "a rotation of the tie points about the vertical (displacement at the block's edge)", "m"),
    ("scale", "a scale of the tie points' horizontal positions (displacement at the block's edge)", "m"),
)
MIN_TIE_POINTS = 3  # fewer ties: no directions of their own to speak of (tilts and rotation need spread)
NAMED_PARAMETERS = 6  # image parameters named per undetermined direction, at most
NULL_TOL = 1e-15  # eigenvalues of the Jacobi-scaled S below this times the largest: null space (the rank check's)
NULL_SHARE = 1e-6  # a direction whose coupling to the images lies this much in the null space is not determined at all
REMEDIES = (
    "give control points (role gcp) spread over the block",
    "give a DEM (pba job --dem DEM.tif): its heights define the height datum",
    "give the RPC images bias priors (pba job --bias-prior PX): the RPCs' own ground reference",
    "weight the platform states and the attitude (options.ephemeris, options.attitude)",
    "or adjust anyway and have the report say it: options.datum.undetermined = \"report\"",
)


@dataclass
class DatumAnalysis:
    """What defines the datum, the seven directions' sigmas, the undetermined ones in words,
    and what ties each image."""

    defined_by: list[str]
    directions: list[dict[str, Any]]
    undetermined: list[dict[str, Any]]
    images: list[dict[str, str]]
    max_sigma_m: float
    remedies: list[str] = field(default_factory=lambda: list(REMEDIES))
    at: str = "initial values"  # where the normal matrix was formed: "initial values" or "solution"

    def to_report(self) -> dict[str, Any]:
        return {
            "at": self.at,
            "defined_by": self.defined_by,
            "max_sigma_m": self.max_sigma_m,
            "directions": self.directions,
            "undetermined": self.undetermined,
            "images": self.images,
            **({"remedies": self.remedies} if self.undetermined else {}),
        }

    def message(self) -> str:
        """One sentence for a refusal or a warning."""
        return undetermined_message(self.undetermined)

    @property
    def unbounded(self) -> bool:
        """Some direction is not determined at all (no finite sigma), not only weakly."""
        return any(u["sigma_m"] is None for u in self.undetermined)


def undetermined_message(undetermined: list[dict[str, Any]]) -> str:
    """The undetermined directions (``quality.datum.undetermined``) in one sentence."""
    parts = []
    for u in undetermined:
        sigma = "not determined at all" if u["sigma_m"] is None else f"sigma {u['sigma_m']:.3g} m"
        moved = f"; it moves {', '.join(u['parameters'])}" if u["parameters"] else ""
        parts.append(f"{u['words']} is not determined ({sigma}{moved})")
    return "; ".join(parts)


def datum_problem(section: dict[str, Any]) -> Problem:
    """The refusal of a job whose datum analysis (``quality.datum``, :meth:`DatumAnalysis.to_report`)
    found undetermined directions."""
    return Problem(
        "datum_undetermined",
        f"the datum is not determined: {undetermined_message(section['undetermined'])}. Defined by: "
        f"{', '.join(section['defined_by']) or 'nothing'}. Remedies: " + "; ".join(section.get("remedies", REMEDIES)),
        ("points",),
        section,
    )


def _tie_functionals(problem: AdjustmentState, parts: SchurParts) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """The seven directions as weights G (n_est, 3, 7) on the estimated points' LGS coordinates
    (zero but for usable tie points), the tie points' mask, and each direction's scale note."""
    est = parts.est_points
    n = len(est)
    g = np.zeros((n, 3, len(DIRECTIONS)))
    ties = np.array([problem.points[p].role == "tie" for p in est], dtype=bool) & ~parts.point_singular
    k = int(ties.sum())
    if k < MIN_TIE_POINTS:
        return g, ties, []
    xyz = np.array([problem.points[p].xyz for p in est])[ties]
    centre = xyz.mean(axis=0)
    x, y = xyz[:, 0] - centre[0], xyz[:, 1] - centre[1]
    radius = float(np.sqrt(np.mean(x**2 + y**2))) or 1.0
    sx, sy = float(np.sum(x**2)) or 1.0, float(np.sum(y**2)) or 1.0
    sr = float(np.sum(x**2 + y**2)) or 1.0
    extent_x = float(np.ptp(x)) or 1.0
    extent_y = float(np.ptp(y)) or 1.0
    rows = np.flatnonzero(ties)
    g[rows, 0, 0] = 1.0 / k
    g[rows, 1, 1] = 1.0 / k
    g[rows, 2, 2] = 1.0 / k
    g[rows, 2, 3] = x / sx * extent_x  # least-squares slope of the heights along east, times the extent
    g[rows, 2, 4] = y / sy * extent_y
    g[rows, 0, 5] = -y / sr * radius  # least-squares rotation (rad) times the mean radius
    g[rows, 1, 5] = x / sr * radius
    g[rows, 0, 6] = x / sr * radius  # least-squares scale times the mean radius
    g[rows, 1, 6] = y / sr * radius
    return g, ties, [extent_x, extent_y, radius]


def _solve_reduced(parts: SchurParts, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S^+ u; the relative size of each column of u's part in the null space of S; that part,
    in the Jacobi-scaled parameters). S's Cholesky factor is the rank check's own
    (:meth:`SchurParts.factor`); where S is singular, the eigen-decomposition."""
    if parts.n_reduced == 0:
        return np.zeros_like(u), np.zeros(u.shape[1]), np.zeros_like(u)
    factor = parts.factor()
    if factor.lower is not None:  # positive definite to working precision: a weak direction shows in its sigma
        return factor.solve(u), np.zeros(u.shape[1]), np.zeros_like(u)
    s = parts.reduced()
    d = np.sqrt(np.clip(np.diag(s), 1e-300, None))
    sn = s / np.outer(d, d)
    un = u / d[:, None]
    with dense_threads.for_matrix(len(d)):
        w, vec = np.linalg.eigh(sn)
    wmax = max(float(w[-1]), 1e-300)
    null = w <= NULL_TOL * wmax
    proj = vec.T @ un
    inv_w = np.where(null, 0.0, 1.0 / np.where(null, 1.0, w))
    x = vec @ (inv_w[:, None] * proj)
    norm = np.linalg.norm(un, axis=0)
    in_null = np.linalg.norm(proj[null], axis=0) / np.where(norm > 0, norm, 1.0)
    return x / d[:, None], in_null, vec[:, null] @ proj[null]


def _defined_by(problem: AdjustmentState) -> list[str]:
    """The sources of the datum in words (counts from the job)."""
    job = problem.job
    out = []
    gcps = [p for p in job.points if p.role == "gcp"]
    if gcps:
        weighted = sum(1 for p in gcps if p.sigma_m is not None and JobSettings.of(job).blocks.control == "weighted")
        out.append(f"{len(gcps)} control point{'s' if len(gcps) != 1 else ''}" + (f" ({weighted} weighted)" if weighted else ""))
    control_lines = [ln for ln in job.lines if getattr(ln, "role", None) == "control"]
    if control_lines:
        out.append(f"{len(control_lines)} control line{'s' if len(control_lines) != 1 else ''}")
    priors = [im.id for im in job.images if im.bias_prior]
    if priors:
        out.append(f"the RPCs' bias priors ({len(priors)} image{'s' if len(priors) != 1 else ''}: {', '.join(priors)})")
    states = [im.id for im in problem.images if _has_state_prior(problem, im)]
    if states:
        out.append(f"weighted platform states ({', '.join(states)})")
    if JobSettings.of(job).blocks.attitude is not None and any(im.attitude for im in job.images):
        out.append("measured attitude (" + ", ".join(im.id for im in job.images if im.attitude) + ")")
    if job.dem is not None:
        n = sum(1 for p in job.points if p.role == "tie" and p.id not in set(job.dem.excluded))
        out.append(f"heights from the DEM ({n} tie points, {job.dem.grid.source})")
    return out


def _has_state_prior(problem: AdjustmentState, img: Any) -> bool:
    """The image's platform state is a weighted observation (its header state or interpolated
    ephemeris with sigmas; the pass models' too)."""
    from solver.observations.ephemeris import image_state

    try:
        state = image_state(problem.job.images[img.index], problem.job.options)
    except (ValueError, KeyError, TypeError):
        return False
    return state is not None and state.sigma_position_m is not None


def _image_ties(problem: AdjustmentState) -> list[dict[str, str]]:
    """What ties each image to the datum, in words."""
    job = problem.job
    role = np.array([p.role for p in problem.points] or [""])
    img = problem.obs.img
    n_img = len(problem.images)
    count_gcp = np.bincount(img[role[problem.obs.pt] == "gcp"], minlength=n_img)
    count_tie = np.bincount(img[role[problem.obs.pt] == "tie"], minlength=n_img)
    n_gcp = {im.id: int(count_gcp[k]) for k, im in enumerate(problem.images)}
    n_tie = {im.id: int(count_tie[k]) for k, im in enumerate(problem.images)}
    states = {im.id for im in problem.images if _has_state_prior(problem, im)}
    out = []
    for im in job.images:
        own = []
        if n_gcp.get(im.id):
            own.append(f"{n_gcp[im.id]} control point observations")
        if im.bias_prior:
            own.append("its RPC bias priors")
        if im.id in states:
            own.append("its weighted platform state")
        if im.attitude and JobSettings.of(job).blocks.attitude is not None:
            own.append("its measured attitude")
        if own:
            tied = ", ".join(own) + (f"; {n_tie.get(im.id, 0)} tie point observations" if n_tie.get(im.id) else "")
        else:
            tied = (f"tie points only ({n_tie.get(im.id, 0)} observations): its orientation comes from the other "
                    "images through them")
        out.append({"image": im.id, "tied_by": tied})
    return out


def analyse_datum(problem: AdjustmentState, lin: Linearisation, parts: SchurParts, names: list[str],
                  max_sigma_m: float) -> DatumAnalysis:
    """The analysis of the module docstring at the current (initial) parameters."""
    g, ties, _scales = _tie_functionals(problem, parts)
    directions: list[dict[str, Any]] = []
    undetermined: list[dict[str, Any]] = []
    if ties.sum() >= MIN_TIE_POINTS:
        v = np.einsum("qab,qbk->qak", parts.c_inv, g)
        u = b_times(lin, parts, v)
        x, in_null, null_part = _solve_reduced(parts, u)
        var = np.einsum("qak,qak->k", g, v) + np.einsum("jk,jk->k", u, x)  # as functional_variances, keeping x
        s_inv_diag: np.ndarray | None = None
        for k, (key, words, _unit) in enumerate(DIRECTIONS):
            infinite = bool(in_null[k] > NULL_SHARE)
            sigma = None if infinite else float(np.sqrt(max(var[k], 0.0)))
            entry = {"direction": key, "words": words, "sigma_m": sigma}
            directions.append(entry)
            if sigma is None or sigma > max_sigma_m:
                if infinite:  # the parameters of the null space that move with it
                    moved = _largest(np.abs(null_part[:, k]), names)
                else:
                    if s_inv_diag is None:
                        s_inv_diag = _reduced_inverse_diagonal(parts.reduced())
                    moved = _moving_parameters(x[:, k], s_inv_diag, names)
                undetermined.append({**entry, "parameters": moved})
    return DatumAnalysis(_defined_by(problem), directions, undetermined, _image_ties(problem), max_sigma_m)


def _reduced_inverse_diagonal(s: np.ndarray) -> np.ndarray:
    """diag(S^+) (pseudo-inverse where S is singular): the image parameters' own variances."""
    d = np.sqrt(np.clip(np.diag(s), 1e-300, None))
    with dense_threads.for_matrix(len(d)):
        w, vec = np.linalg.eigh(s / np.outer(d, d))
    keep = w > NULL_TOL * max(float(w[-1]), 1e-300)
    return ((vec[:, keep] ** 2) / w[keep]).sum(axis=1) / d**2


def _moving_parameters(cov: np.ndarray, var: np.ndarray, names: list[str]) -> list[str]:
    """The image parameters most correlated with an undetermined direction (their covariance
    with it relative to their own sigma), named "image/parameter"."""
    if cov.size == 0:
        return []
    return _largest(np.abs(cov) / np.sqrt(np.where(var > 0, var, np.inf)), names)


def _largest(weight: np.ndarray, names: list[str]) -> list[str]:
    """The names of the largest weights (at least half the largest; at most NAMED_PARAMETERS)."""
    if weight.size == 0:
        return []
    order = np.argsort(-weight)
    top = float(weight[order[0]])
    return [names[j] for j in order[:NAMED_PARAMETERS] if top > 0 and weight[j] >= 0.5 * top]


def functional_variances(lin: Linearisation, parts: SchurParts, g: np.ndarray, s_inv: np.ndarray | None = None) -> np.ndarray:
    """g^T N^-1 g (a-priori scale) of point-space functionals ``g`` (n_est, 3, k) on the
    estimated points' LGS coordinates (module docstring; infinite where S is singular along it).
    ``s_inv``: the inverse of the reduced matrix S where it is known already (the covariance's,
    kept with the report's linearisation; S is then positive definite and ``parts`` may have
    dropped it), else S is solved through its factor."""
    v = np.einsum("qab,qbk->qak", parts.c_inv, g)
    u = b_times(lin, parts, v)
    if s_inv is not None:
        x, in_null = s_inv @ u, np.zeros(u.shape[1])
    else:
        x, in_null, _ = _solve_reduced(parts, u)
    var = np.einsum("qak,qak->k", g, v) + np.einsum("jk,jk->k", u, x)
    return np.where(in_null > NULL_SHARE, np.inf, var)


def dem_bias_test(residual_w: np.ndarray, a_w: np.ndarray, hat: float, alpha: float) -> dict[str, Any]:
    """The test of a common DEM bias b (metres) added to every DEM height, from the whitened
    residuals ``residual_w`` of the DEM heights, the whitened design column of b ``a_w`` (1/sigma
    per DEM height) and ``hat`` = a^T H a (H = J N^-1 J^T, the hat matrix of the whole
    adjustment; :func:`functional_variances` of the DEM rows' Jacobian onto the points)::

        b = a^T r / (a^T a - hat),  sigma_b = 1 / sqrt(a^T a - hat),  w = b / sigma_b

    (the estimate b would take as one more parameter; a^T a - hat = a^T Q_vv P a). ``w`` is
    standard normal without a bias; |w| beyond the two-sided ``alpha`` quantile rejects. When the
    DEM alone defines the heights, a^T a - hat is about zero: not testable."""
    from solver.quality.distributions import normal_quantile

    info = float(a_w @ a_w) - hat
    critical = float(normal_quantile(1.0 - alpha / 2.0))
    if not np.isfinite(info) or info <= 1e-6 * float(a_w @ a_w):
        return {"testable": False, "critical": critical,
                "reason": "the DEM alone fixes the heights: a common DEM bias moves every height with it and cannot be seen"}
    b = float(a_w @ residual_w) / info
    sigma = 1.0 / np.sqrt(info)
    w = b / sigma
    return {"testable": True, "bias_m": b, "sigma_m": float(sigma), "w": float(w), "critical": critical,
            "passed": bool(abs(w) <= critical)}


def dem_bias(problem: AdjustmentState, lin: Linearisation, parts: SchurParts, alpha: float, s_inv: np.ndarray | None = None) -> dict[str, Any] | None:
    """:func:`dem_bias_test` of the DEM heights of ``problem`` (the family named "dem") at its
    current parameters: a = 1/sigma per DEM height, r its whitened residual, and a^T H a from the
    DEM rows' Jacobian onto the points (w_i^2 dv/dp per point). None without DEM heights.
    ``s_inv``: the reduced matrix's inverse when known (:func:`functional_variances`)."""
    dem_terms = [t for t in lin.terms if t.family.name == "dem" and t.block == "point"]
    if not dem_terms:
        return None
    pt_q = {int(p): q for q, p in enumerate(parts.est_points)}
    g = np.zeros((len(parts.est_points), 3, 1))
    a_w, r_w = [], []
    for labelled in dem_terms:
        term = labelled.term
        q = pt_q.get(int(labelled.index))
        r, jac = term.evaluate(problem.points[labelled.index].xyz)
        a_w.append(term.w)
        r_w.append(float(r[0]))
        if q is not None:
            g[q, :, 0] += term.w * jac[0]  # J_i^T a_i (whitened row times a_i = w_i)
    hat = float(functional_variances(lin, parts, g, s_inv)[0])
    return dem_bias_test(np.array(r_w), np.array(a_w), hat, alpha)
