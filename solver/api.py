"""The solver's public entry points, used by the CLI and by the service's workers.

    validate(job)                      -> dict   dry run: schema, references, degrees of freedom
    run(job, progress=..., cancel=...) -> dict   the adjustment report (JSON-ready)
    Handover(document)                 -> a job document handed to run/compare once, freed once parsed
    validation_record(summary)         -> dict   a validate() to hand to run(validated=...)
    compare(job, models, ...)          -> dict   one report per model plus a side-by-side table
    preanalyse(job)                    -> dict   predicted precision of a planned block (no measurements)

``progress(fraction, message, info)`` is called with ``fraction`` in [0, 1] that never
decreases, a short human message and a dict (``iteration``, ``cost`` when solving).
``cancel()`` returns True when the caller wants the solve stopped; the solve then raises
:class:`solver.errors.Cancelled` within one solver iteration.

Bad input raises :class:`solver.errors.JobError` (with every problem found); a solve that
does not converge is a normal report with ``adjustment.converged = false``; a solve that leaves
no usable solution (Ceres FAILURE, a non-finite cost, no successful iteration) raises
:class:`solver.errors.UnusableSolution`, a JobError (docs/report-contract.md). As a last line of
defence, an arithmetic, linear-algebra or PROJ failure that escapes the checks (numbers the
validation let through but the mathematics cannot use) is also a JobError, ``unusable_values``
located at the document's root; any other exception is a bug of the solver and propagates.
"""

from __future__ import annotations

import gc
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Protocol

import numpy as np
from pyproj.exceptions import ProjError

from solver.engine import dense_threads
from solver.errors import JobError, Problem
from solver.schema.job import Job, load_job
from solver.schema.settings import JobSettings

# failures that only the numbers of a document can cause in code that passed its tests
CLIENT_FAULTS = (ArithmeticError, np.linalg.LinAlgError, ProjError)


@contextmanager
def _gc_paused() -> Iterator[None]:
    """Python's cyclic garbage collector paused for the call: an adjustment allocates millions
    of small containers (the parsed observations, arrays' lists, report entries), all freed by
    reference counting, and the collector would otherwise walk the growing heap again and again
    meanwhile (measured: seconds per 100,000 observations in parsing and in the report)."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if collecting:
            gc.enable()


@contextmanager
def _input_faults_as_job_errors() -> Iterator[None]:
    try:
        with _gc_paused():
            yield
    except CLIENT_FAULTS as exc:
        raise JobError(
            Problem(
                "unusable_values",
                f"the job's numbers cannot be used by the adjustment ({type(exc).__name__}: {exc}); "
                "check coordinates, states, camera constants and sigmas",
                (),
            )
        ) from exc


class ProgressFn(Protocol):
    def __call__(self, fraction: float, message: str, info: dict[str, Any] | None = None) -> None: ...


KERNELS_COMPILING = "kernels_compiling"  # key of the progress info of a compiling notice


@contextmanager
def _kernel_notices(progress: ProgressFn | None) -> Iterator[ProgressFn | None]:
    """The progress function, which also hears (at the fraction reached, with
    ``info[KERNELS_COMPILING] = True``) when kernels missing from the cache compile, a minute or
    more that would otherwise look like a hang (solver/kernels/cache.py)."""
    if progress is None:
        yield None
        return
    reached = [0.0]

    def tracked(fraction: float, message: str, info: dict[str, Any] | None = None) -> None:
        reached[0] = max(reached[0], fraction)
        progress(fraction, message, info)

    from solver.kernels.cache import compile_notices

    with compile_notices(lambda message: progress(reached[0], message, {KERNELS_COMPILING: True})):
        yield tracked


CancelFn = Callable[[], bool]


class Handover:
    """A job document (dict or JSON text) handed to :func:`run` or :func:`compare` once, for a
    caller that keeps no reference to it: the solver takes it out of the holder when it parses
    it, and the document is freed as soon as the job exists, before the problem is built (at a
    million image observations the parsed JSON is about 550 MB, more than the job). Called as
    ``run(Handover(document))`` with no other reference to ``document`` left (``del`` it, or
    ``document.pop("job")``); the holder is empty afterwards and cannot be handed again."""

    __slots__ = ("_document",)

    def __init__(self, document: dict[str, Any] | str | bytes) -> None:
        self._document: dict[str, Any] | str | bytes | None = document

    def take(self) -> dict[str, Any] | str | bytes:
        """The document, once (the holder then holds nothing; RuntimeError the second time)."""
        document, self._document = self._document, None
        if document is None:
            raise RuntimeError("this job document was handed over already")
        return document


JobInput = Job | dict[str, Any] | str | bytes | Handover
"""What the entry points take: the parsed job, its document (dict or JSON text), or a
:class:`Handover` of the document."""


def _as_job(job: JobInput) -> Job:
    if isinstance(job, Handover):
        job = job.take()  # held only by this frame now: freed when it returns
    return job if isinstance(job, Job) else load_job(job)  # inside the guard: parsing allocates most


def validate(job: JobInput) -> dict[str, Any]:
    """Check a job without solving it.

    Returns ``{"valid": bool, "problems": [...], "n_observations", "n_unknowns", "dof",
    "images": [{"id", "model", "n_parameters"}]}``. Schema errors raise pydantic's
    ValidationError (the caller maps it); everything else is reported in ``problems``.
    """
    from solver.engine.validate import validate_job

    with _input_faults_as_job_errors():
        return validate_job(_as_job(job))


def run(
    job: JobInput,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
    validated: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Adjust a job and return its report (docs/report-contract.md; built by
    :func:`solver.report.document.assess`).

    If ``job.options.models`` is not empty this is a model comparison (same as :func:`compare`).
    ``validated``: the record of a validation already made (:func:`validation_record` of
    :func:`validate`'s counts, e.g. at a server's submission); when it was made by this code
    the job is not checked again. ``job`` handed as :class:`Handover` is freed once parsed.
    """
    from solver.engine.validate import handed

    with _gc_paused():
        j = _as_job(job)
        del job  # this frame's reference to the caller's document (a Handover is empty now)
        models = list(JobSettings.of(j).procedures.models)
        if models:
            return compare(j, models, progress=progress, cancel=cancel, validated=validated)
        from solver.adjust import adjust_job

        with _input_faults_as_job_errors(), dense_threads.bounded(), _kernel_notices(progress) as progress:
            return adjust_job(handed(j, validated), progress=progress, cancel=cancel)


def validation_record(summary: dict[str, Any]) -> dict[str, Any]:
    """What to hand to :func:`run` with a job :func:`validate` found valid (its counts and
    the fingerprint of the checks that ran)."""
    from solver.engine.validate import validation_record as record

    return record({k: v for k, v in summary.items() if k in ("n_observations", "n_unknowns", "dof")})


def compare(
    job: JobInput,
    models: list[str],
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
    validated: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Adjust the same observations with each platform model; one report per model + a table.
    ``validated`` as in :func:`run`: the job is not checked again for each model."""
    from solver.compare import compare_models

    with _input_faults_as_job_errors(), dense_threads.bounded(), _kernel_notices(progress) as progress:
        return compare_models(_as_job(job), models, progress=progress, cancel=cancel, validated=validated)


def preanalyse(job: JobInput) -> dict[str, Any]:
    """Pre-analysis of a planned block: the predicted precision of its check and ground points
    from planned coordinates and the approximate orientation, before anything is measured
    (:mod:`solver.quality.preanalysis`; ``kind: "preanalysis"`` in docs/report-contract.md)."""
    from solver.quality.preanalysis import preanalyse as _preanalyse

    with _input_faults_as_job_errors(), dense_threads.bounded():
        return _preanalyse(_as_job(job))


def preanalysis_problems(job: JobInput) -> list[Problem]:
    """What makes a job unusable as a pre-analysis before any computation (planned points
    without coordinates); the rest is found when it runs."""
    from solver.engine.validate import planning_problems  # light: the server checks pre-analyses in its API process

    return planning_problems(_as_job(job))
