"""Problem-document entries (JSON pointer, code, message), free of web-framework imports so
worker processes can build them too."""

from __future__ import annotations

from typing import Any, Iterable, Sequence

from solver.errors import JobError


def json_pointer(location: Iterable[str | int]) -> str:
    """RFC 6901 pointer of a location tuple: ``("a", 0, "b/c")`` -> ``/a/0/b~1c``."""
    parts = [str(p).replace("~", "~0").replace("/", "~1") for p in location]
    return "/" + "/".join(parts) if parts else ""


def pydantic_errors(
    errors: Iterable[Any], prefix: Sequence[str | int] = ()
) -> list[dict[str, Any]]:
    """pydantic error dicts as entries (pointer, code, message), never echoing the input."""
    out = []
    for e in errors:
        loc = [p for p in e.get("loc", ()) if p != "body"]
        # pydantic inserts tags such as "function-after[_check(), Camera]" into locations
        loc = [p for p in loc if not (isinstance(p, str) and "[" in p and p.endswith("]"))]
        out.append(
            {
                "pointer": json_pointer([*prefix, *loc]),
                "code": str(e.get("type", "invalid")),
                "message": str(e.get("msg", "invalid value")),
            }
        )
    return out


def problem_entries(
    problems: Iterable[dict[str, Any]], prefix: Sequence[str | int] = ("inputs", "job")
) -> list[dict[str, Any]]:
    """Solver problem dicts (``Problem.to_dict()``) as entries pointing into the request."""
    return [
        {
            "pointer": json_pointer([*prefix, *p.get("location", [])]),
            "code": str(p.get("code", "invalid")),
            "message": str(p.get("message", "")),
            **({"detail": p["detail"]} if p.get("detail") else {}),
        }
        for p in problems
    ]


def job_error_entries(
    exc: JobError, prefix: Sequence[str | int] = ("inputs", "job")
) -> list[dict[str, Any]]:
    """The problems of a solver :class:`JobError` as entries."""
    return problem_entries([p.to_dict() for p in exc.problems], prefix)
