"""Measured attitude as weighted observations of the orbit-attitude and pass models.

Those models' rotation is ``M(t) = Ry(mounting) Rx(roll) Ry(pitch) Rz(yaw) R_orbit(S(t), V(t))``
with each angle a polynomial in the attitude time t_a (docs/models.md sections 10 and 12)::

    angle(t_a) = c0 + c1 t_a + c2 t_a^2 + c3 t_a^3      (rad; t_a in s)

With an attitude base (``images[].attitude_base``, the delivered attitude interpolated
linearly, :func:`solver.kernels.platform._attitude_base_into`) each angle is the base plus the
polynomial, and a sample observes the polynomial as ``measured - base(t_a)``; the block's
samples then enter as what they say of that correction (:func:`reduced_term`: per angle as
many rows as it has free terms, one test for the block, no sample removable).

An attitude sample (roll, pitch, yaw relative to the orbital frame at epoch t, images[].attitude)
therefore observes a linear function of the attitude coefficients, ``r = W (A p - b)``, the same
form as the state priors (:class:`solver.observations.state_priors.StatePrior`, reused here). t_a is the time
since the image's first line for per-image attitude (OA-*, PASS-* with ``attitude: image``) and
the time since the pass reference epoch for an attitude block shared by the images of one
camera (PASS-* default).

Each attitude block (one image, or the images sharing one) uses each *distinct* sample (by
epoch) of its images once, when the epoch lies within the block's lines: a sample carried by
three images of a shared block is one observation, not three, and the polynomials are not
asked to extrapolate outside the time they describe.

Correlated errors (``options.attitude.bias_sigma_deg``): telemetry errs mostly by one bias per
block and angle plus a small white noise, so the n samples of one block and angle have the
covariance ``Sigma = sigma_w^2 I + sigma_b^2 11^T`` (``sigma_w``: ``sigma_deg``). The residuals
are whitened by its symmetric inverse square root, in closed form (:func:`bias_shrink`)::

    Sigma^(-1/2) = (I - c/n 11^T) / sigma_w,   c = 1 - sigma_w / sqrt(sigma_w^2 + n sigma_b^2)

so a sample's whitened residual is its residual minus the fraction c of the block's mean
residual for that angle, in units of sigma_w: the least-squares cost is ``r^T Sigma^-1 r``, and
the covariance, redundancy numbers and global test follow from the whitened rows as for every
other term. Each sample's three whitened rows stay its test group (data snooping): the test of
a sample is of its departure from the block's common error (the component in the direction of
one sample's bias deviates from it by about 1/sqrt(n)), its sigma ``sigma_w``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.blocks.platform import attitude_base_at, attitude_blocks, attitude_time_offset, image_attitude_blocks
from solver.errors import Problem
from solver.observations.family import Count, FamilyDefaults, GroupSpec, Labelled, ReportContext, per_row_groups
from solver.observations.passes import pass_line_span
from solver.observations.state_priors import StatePrior
from solver.platforms import coef_index, get_model
from solver.schema.settings import JobSettings

if TYPE_CHECKING:
    from solver.schema.job import AttitudeSample, Job
    from solver.state import AdjustmentState

ANGLES = ("omega", "phi", "kappa")  # the coefficient slots of roll, pitch, yaw


def bias_shrink(n: int, sigma_w: float, sigma_b: float) -> float:
    """c of the whitening ``Sigma^(-1/2) = (I - c/n 11^T) / sigma_w`` of n samples with the
    covariance ``sigma_w^2 I + sigma_b^2 11^T`` (module doc); 0 without a bias."""
    return 1.0 - sigma_w / math.sqrt(sigma_w**2 + n * sigma_b**2)


@dataclass
class AttitudeTerm(StatePrior):
    """The attitude samples of one block, ``r = Sigma^(-1/2) (A p - b)``: rows sample by sample
    (roll, pitch, yaw), ``w`` = 1/sigma_w per row and ``shrink`` = c/n per angle (module doc;
    None: independent samples, ``r = W (A p - b)`` exactly)."""

    shrink: np.ndarray | None = None  # (3,)
    reduced: bool = False  # the rows are :func:`reduced_term`'s (an attitude base): one group, not per sample

    def whiten(self, x: np.ndarray) -> np.ndarray:
        """``Sigma^(-1/2) x`` for ``x`` (m,) or (m, k) in the term's row order."""
        w = self.w if x.ndim == 1 else self.w[:, None]
        if self.shrink is None:
            return w * x
        y = x.reshape(-1, 3, *x.shape[1:])
        s = self.shrink.reshape(1, 3, *([1] * (x.ndim - 1)))
        return w * (y - s * y.sum(axis=0, keepdims=True)).reshape(x.shape)

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.whiten(self.a @ params - self.b), self.whiten(self.a)

    def linear_form(self) -> tuple[np.ndarray, np.ndarray]:
        return self.whiten(self.a), self.whiten(self.b)

    def raw(self, params: np.ndarray) -> np.ndarray:
        """``A p - b`` (rad): model minus measured, sample by sample."""
        return self.a @ params - self.b


def block_samples(job: "Job", images: list[int]) -> list["AttitudeSample"]:
    """The distinct attitude samples (by epoch) of a block's images that lie within the time
    span of its images' lines, by epoch."""
    return [sample for _i, sample in _carried_samples(job, images)]


def _carried_samples(job: "Job", images: list[int]) -> list[tuple[int, "AttitudeSample"]]:
    """:func:`block_samples` with the image that carries each (the first of the block's images
    that has it)."""
    if any(job.images[i].first_line_time_s is None for i in images):
        return []
    lo, hi = pass_line_span(job, images)
    seen: dict[float, tuple[int, "AttitudeSample"]] = {}
    for i in images:
        for sample in job.images[i].attitude:
            if lo <= sample.time_s <= hi:
                seen.setdefault(float(sample.time_s), (i, sample))
    return [seen[t] for t in sorted(seen)]


def _based(job: "Job", block: list[int]) -> bool:
    """Whether the block's images carry an attitude base (their samples then observe its correction)."""
    return any(job.images[i].attitude_base for i in block)


def _reduced_rows(job: "Job", block: list[int], n: int) -> int:
    """Rows of :func:`reduced_term` for ``n`` samples: per angle, its free polynomial terms (at most n)."""
    im = job.images[block[0]]
    try:
        free = {int(k) for k in get_model(im.model.name).free_indices(dict(im.model.options))}
    except (KeyError, ValueError):
        return 3 * n  # reported by the model check
    return sum(min(n, sum(coef_index(e, p) in free for p in range(4))) for e in ANGLES)


def n_attitude_observations(job: "Job") -> int:
    """How many weighted attitude observations :func:`attitude_terms` will make (validation)."""
    if JobSettings.of(job).blocks.attitude is None:
        return 0
    total = 0
    for block in attitude_blocks(job):
        n = len(block_samples(job, block))
        total += _reduced_rows(job, block, n) if n and _based(job, block) else 3 * n
    return total


def reduced_term(term: AttitudeTerm) -> AttitudeTerm:
    """The attitude observations of a block whose images carry an attitude base, as what they say
    of the correction: per angle, the whitened rows ``Sigma^(-1/2) (A p - b)`` replaced by
    ``R p - Q^T Sigma^(-1/2) b`` (``Sigma^(-1/2) A = Q R`` on the angle's free columns). The
    estimate, its covariance and every other row's redundancy are the same; what no correction
    can change (the samples' departure from the base beyond a polynomial: zero when the base is
    the samples, as :mod:`solver.sensors.job_fragment` writes it) is left out, with its degrees
    of freedom, instead of counting as residuals that fit far better than their weights."""
    wa, wb = term.whiten(term.a), term.whiten(term.b)
    n = term.a.shape[0] // 3
    rows_a, rows_b = [], []
    for e in range(3):
        sel = np.arange(e, 3 * n, 3)
        cols = np.flatnonzero(np.any(term.a[sel] != 0.0, axis=0))
        if cols.size == 0:
            continue
        q, r = np.linalg.qr(wa[np.ix_(sel, cols)])
        a = np.zeros((r.shape[0], term.a.shape[1]))
        a[:, cols] = r
        rows_a.append(a)
        rows_b.append(q.T @ wb[sel])
    a = np.vstack(rows_a) if rows_a else np.zeros((0, term.a.shape[1]))
    b = np.concatenate(rows_b) if rows_b else np.zeros(0)
    return AttitudeTerm(term.image_index, a, b, np.ones(b.shape[0]), None, reduced=True)


def attitude_problems(job: "Job") -> list[tuple[str, str, tuple]]:
    """(code, message, location) of attitude samples that cannot be used as asked."""

    out: list[tuple[str, str, tuple]] = []
    if JobSettings.of(job).blocks.attitude is None:
        return out
    blocked = {i for block in attitude_blocks(job) for i in block}  # the images whose attitude is relative to the orbital frame
    for i, im in enumerate(job.images):
        if not im.attitude:
            continue
        try:
            model = get_model(im.model.name)
        except KeyError:
            continue  # reported by the model check
        if i not in blocked:
            out.append(
                (
                    "attitude_needs_orbital_frame",
                    f"image {im.id!r}: attitude samples are roll, pitch and yaw relative to the "
                    f"orbital frame, but model {model.name} has Earth-fixed angles; use an "
                    "orbit-attitude (OA-*) or pass (PASS-*) model, or drop options.attitude",
                    ("images", i, "attitude"),
                )
            )
        elif im.first_line_time_s is None:
            out.append(
                (
                    "attitude_needs_epoch",
                    f"image {im.id!r}: attitude samples need the image's first_line_time_s",
                    ("images", i, "first_line_time_s"),
                )
            )
    return out


def _block_terms(problem: "AdjustmentState") -> list[tuple[list[int], AttitudeTerm]]:
    """(image indices of the block, its term) per attitude block with samples: one linear term
    of 3 rows per sample on the block's parameters (those of its first image)."""
    job = problem.job
    opts = JobSettings.of(job).blocks.attitude
    if opts is None:
        return []
    w_angle = [1.0 / math.radians(s) for s in opts.sigma_deg]
    bias = opts.bias_sigma_deg
    out = []
    for block in image_attitude_blocks(problem.images):
        carried = _carried_samples(job, block)
        if not carried:
            continue
        samples = [sample for _i, sample in carried]
        img = problem.images[block[0]]
        t_first = job.images[block[0]].first_line_time_s
        offset = attitude_time_offset(img)
        where = {int(j): q for q, j in enumerate(img.free_idx)}
        rows_a, rows_b, rows_w = [], [], []
        for i, sample in carried:
            t_a = sample.time_s - t_first + offset
            observed = (sample.roll_deg, sample.pitch_deg, sample.yaw_deg)
            # the attitude base of the image carrying the sample (its angle time is the block's
            # for the images that share one): the polynomials observe what it leaves
            base = attitude_base_at(problem.images[i], np.array([sample.time_s - job.images[i].first_line_time_s
                                                                  + attitude_time_offset(problem.images[i])]))[0]
            for e, element in enumerate(ANGLES):
                row = np.zeros(img.nfree)
                b = math.radians(observed[e]) - base[e]
                for power in range(4):
                    k = coef_index(element, power)
                    if k in where:
                        row[where[k]] = t_a**power
                    else:  # a held coefficient: a known part of the angle
                        b -= img.base[k] * t_a**power
                rows_a.append(row)
                rows_b.append(b)
                rows_w.append(w_angle[e])
        shrink = None
        if bias is not None:
            n = len(samples)
            shrink = np.array([bias_shrink(n, sw, sb) / n for sw, sb in zip(opts.sigma_deg, bias)])
        out.append((block, AttitudeTerm(img.index, np.array(rows_a), np.array(rows_b), np.array(rows_w), shrink)))
    return out


def attitude_terms(problem: "AdjustmentState") -> list[AttitudeTerm]:
    """The weighted attitude observations: one term per attitude block with samples."""
    return [term for _block, term in _block_terms(problem)]


def attitude_report(problem: "AdjustmentState") -> list[dict]:
    """The report's ``attitude`` section: per attitude block with weighted samples, its images,
    the number of samples, the sigmas (with ``bias_sigma_deg``: the white part) and the
    residuals (measured - adjusted, deg) at the current parameters: RMS and largest absolute
    value per angle (roll, pitch, yaw)."""
    out = []
    opts = JobSettings.of(problem.job).blocks.attitude
    for block, term in _block_terms(problem):
        resid = -np.degrees(term.raw(problem.images[term.image_index].params)).reshape(-1, 3)  # measured - model
        out.append(
            {
                "images": [problem.images[i].id for i in block],
                "n_samples": int(resid.shape[0]),
                "sigma_deg": [float(s) for s in opts.sigma_deg],
                "rms_residual_deg": [float(x) for x in np.sqrt(np.mean(resid**2, axis=0))],
                "max_abs_residual_deg": [float(x) for x in np.abs(resid).max(axis=0)],
            }
        )
    return out


def _without_samples(job: "Job", removals: list[tuple]) -> "Job":
    """``job`` without the attitude samples ``("attitude_sample", image id, time_s)``: the sample
    of that image at that epoch, and the same sample (epoch and angles) in the images sharing it."""
    gone = [(r[1], r[2]) for r in removals if r[0] == "attitude_sample"]
    if not gone:
        return job
    images = {im.id: im for im in job.images}
    drop = set()
    for image, t in gone:
        for s in images[image].attitude:
            if abs(s.time_s - t) < 1e-9:
                drop.add((s.time_s, s.roll_deg, s.pitch_deg, s.yaw_deg))
    new = [
        im.model_copy(update={"attitude": [s for s in im.attitude if (s.time_s, s.roll_deg, s.pitch_deg, s.yaw_deg) not in drop]})
        for im in job.images
    ]
    return job.model_copy(update={"images": new})


class MeasuredAttitude(FamilyDefaults):
    """Measured attitude (``options.attitude`` and the images' ``attitude`` samples) as an
    observation family (:class:`solver.observations.family.ObservationFamily`): one test per
    sample (roll, pitch, yaw), removable; its report section ``attitude`` lists the removed
    samples' epochs (``rejected_samples_s``)."""

    name = "attitude"

    def check(self, job: "Job") -> tuple[list[Problem], Count]:
        issues = [Problem(code, msg, loc) for code, msg, loc in attitude_problems(job)]
        n = 0 if issues else n_attitude_observations(job)
        return issues, Count(n_observations=n, datum=frozenset({"attitude"}) if n else frozenset())

    def terms(self, problem: "AdjustmentState") -> list[Labelled]:
        """One term per attitude block; a block with an attitude base as :func:`reduced_term`."""
        return [Labelled(self, reduced_term(term) if _based(problem.job, block) else term, "image", term.image_index, block)
                for block, term in _block_terms(problem)]

    def initialise(self, problem: "AdjustmentState") -> None:
        """Each block's attitude polynomials fitted to its weighted samples (weighted least
        squares, minimum norm where the samples do not fix a coefficient): an agile satellite
        looks 10-30 degrees off the orbital frame, and tie rays started from the nominal
        attitude miss each other by kilometres. (The engine applies the job's own ``initial``
        values after this.)"""
        for block, term in _block_terms(problem):
            cols = np.flatnonzero(np.any(term.a != 0.0, axis=0))
            if cols.size == 0:
                continue
            fitted = np.linalg.lstsq(term.whiten(term.a[:, cols]), term.whiten(term.b), rcond=None)[0]
            for i in block:  # a shared block's images share one parameter vector
                img = problem.images[i]
                img.base[img.free_idx[cols]] = fitted
                img.params[:] = img.base[img.free_idx]

    def groups(self, problem: "AdjustmentState", labelled: Labelled) -> list[GroupSpec]:
        block, term = labelled.tag, labelled.term
        if term.reduced:  # the correction's rows: one test of the block, not removable (a sample is also the base)
            k = term.n_residuals
            return [GroupSpec("attitude_correction", np.arange(k), {"image": problem.images[block[0]].id}, np.ones(k), "",
                              [f"row {j}" for j in range(k)], -1.0, None)]
        samples = block_samples(problem.job, block)
        return per_row_groups(
            "attitude_sample", term.n_residuals, 3, {"image": problem.images[block[0]].id},
            [{"time_s": float(s.time_s)} for s in samples], np.degrees(1.0 / term.w), "deg", ["roll", "pitch", "yaw"],
            -1.0, lambda lab: ("attitude_sample", lab["image"], lab["time_s"]),
        )

    def report(self, problem: "AdjustmentState", ctx: ReportContext) -> dict[str, Any]:
        return {"attitude": attitude_report(problem)}

    def without(self, job: "Job", removals: list[tuple]) -> tuple["Job", list[dict[str, Any]]]:
        return _without_samples(job, removals), []

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        """``attitude[].rejected_samples_s``: the epochs (s, the job's time scale) of the samples
        removed from that attitude block."""
        block_of = {}
        for block in report.get("attitude") or []:
            block["rejected_samples_s"] = []
            block_of.update({image: block for image in block.get("images") or []})
        for r in removed:
            if r["kind"] == "attitude_sample" and r.get("image") in block_of:
                block_of[r["image"]]["rejected_samples_s"].append(r.get("time_s"))


FAMILY = MeasuredAttitude()
