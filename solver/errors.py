"""Domain exceptions of the solver.

Every error a user can cause by what they put in a job is a :class:`JobError` (or a subclass).
It carries a machine-readable ``code``, a human sentence, and the ``location`` in the job
document (a JSON-pointer-like tuple such as ``("observations", 12, "line")``) so that the CLI
and the HTTP service can point at the offending field. The service maps these to 4xx problem
documents in one place; nothing here knows about HTTP.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class Problem:
    """One problem found in a job: what, where, and an optional detail payload."""

    code: str
    message: str
    location: tuple[str | int, ...] = ()
    detail: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "code": self.code,
            "message": self.message,
            "location": list(self.location),
            **({"detail": self.detail} if self.detail else {}),
        }


class SolverError(Exception):
    """Base class of all solver exceptions."""


class JobError(SolverError):
    """The job document cannot be solved as given. Holds one or more :class:`Problem`."""

    def __init__(self, problems: list[Problem] | Problem):
        self.problems = [problems] if isinstance(problems, Problem) else list(problems)
        shown = "; ".join(p.message for p in self.problems[:5])
        more = len(self.problems) - 5
        super().__init__(shown + (f"; and {more} more problem(s)" if more > 0 else ""))

    @property
    def code(self) -> str:
        return self.problems[0].code if self.problems else "invalid_job"

    def to_dict(self) -> dict[str, Any]:
        return {"problems": [p.to_dict() for p in self.problems]}


class RankDeficientError(JobError):
    """The normal equations are singular: the control geometry does not fix these parameters."""


class UnusableSolution(JobError):
    """The solve ended without a usable solution (Ceres termination FAILURE, a non-finite cost,
    or no successful iteration): the job fails instead of reporting its starting values as an
    adjustment. The problem's ``detail`` carries the termination, iterations and costs."""

    @classmethod
    def from_outcome(cls, reasons: list[str], detail: dict[str, Any]) -> "UnusableSolution":
        return cls(
            Problem(
                "unusable_solution",
                "the adjustment did not produce a usable solution: " + "; ".join(reasons),
                (),
                {"reasons": reasons, **detail},
            )
        )


class Cancelled(SolverError):
    """The solve was cancelled through the cancellation hook."""
