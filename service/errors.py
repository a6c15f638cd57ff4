"""Service exceptions and their mapping to RFC 7807 problem documents, in one place.

Routes raise the exceptions below (or let the solver's :class:`~solver.errors.JobError`
and pydantic's ``ValidationError`` propagate); :func:`install_error_handlers` turns each into
``application/problem+json`` with the right status. Entries of ``errors`` carry a JSON
pointer (RFC 6901) to the offending field of the request body.
"""

from __future__ import annotations

import logging
import re
from typing import Any, Sequence

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.problems import job_error_entries, pydantic_errors
from service.states import FailureCode
from solver.errors import JobError
from solver.report.json_text import json_ready

log = logging.getLogger("pba.service")

PROBLEM_MEDIA_TYPE = "application/problem+json"
MAX_ERRORS = 100
OGC_EXC = "http://www.opengis.net/def/exceptions/ogcapi-processes-1/1.0/"


PROBLEM_DESCRIPTIONS = {
    400: "Bad request: malformed JSON (NaN included) or an invalid parameter",
    401: "API key missing or not valid",
    403: "Forbidden: the key is valid but not allowed here (e.g. another user's shared camera)",
    404: "Not found (also: a job of another user)",
    409: "Conflict with the state of the resource",
    413: "Request body or job over the size limit, or the user's storage quota is used up",
    415: "The request body is not JSON (Content-Type must be application/json)",
    422: "Invalid input; each entry of errors points at the offending field",
    429: "Too many queued jobs for this user",
    500: "The job failed on the server side (worker crash, time limit)",
    503: "Service unavailable: not ready yet, or a computation process stopped (retry)",
}


def problem_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries for problem documents with these status codes."""
    from service.schemas import Problem

    return {
        code: {
            "model": Problem,
            "description": PROBLEM_DESCRIPTIONS[code],
            "content": {PROBLEM_MEDIA_TYPE: {"schema": {"$ref": "#/components/schemas/Problem"}}},
        }
        for code in codes
    }


def problem_type(code: str) -> str:
    """The ``type`` URI of one of this service's problems."""
    return f"urn:pba:problem:{code}"


class ServiceError(Exception):
    """Base class: an error with an HTTP status, a problem type and optional field errors."""

    status: int = 400
    code: str = "bad-request"
    title: str = "Bad request"

    def __init__(
        self,
        detail: str,
        errors: Sequence[dict[str, Any]] | None = None,
        type_uri: str | None = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(detail)
        self.detail = detail
        self.errors = list(errors or [])
        self.type_uri = type_uri or problem_type(self.code)
        self.headers = headers or {}


class NotFound(ServiceError):
    status, code, title = 404, "not-found", "Not found"


class NoSuchJob(NotFound):
    code, title = "no-such-job", "No such job"

    def __init__(self, job_id: str) -> None:
        super().__init__(f"there is no job {job_id!r}", type_uri=OGC_EXC + "no-such-job")


class NoSuchProcess(NotFound):
    code, title = "no-such-process", "No such process"

    def __init__(self, process_id: str) -> None:
        super().__init__(
            f"there is no process {process_id!r}", type_uri=OGC_EXC + "no-such-process"
        )


class ResultNotReady(NotFound):
    code, title = "result-not-ready", "Result not ready"

    def __init__(self, detail: str) -> None:
        super().__init__(detail, type_uri=OGC_EXC + "result-not-ready")


class JobDismissed(NotFound):
    code, title = "job-dismissed", "The job was dismissed"


class InvalidInput(ServiceError):
    """The request is well-formed JSON but not an acceptable job."""

    status, code, title = 422, "invalid-input", "Invalid input"


def failed_job_status(error: dict[str, Any] | None) -> int:
    """HTTP status of a failed job's results, from the code its stored error keeps: 500 when
    the server failed it (:class:`service.states.FailureCode`, or no code recorded), 422 when
    its content did (a solver problem code, ``invalid-input``). Errors stored before codes
    alone were kept carry their ``status``, which is honoured."""
    error = error or {}
    code = error.get("code")
    if code is None:
        legacy = error.get("status")
        return legacy if isinstance(legacy, int) and 400 <= legacy <= 599 else 500
    return 500 if code in set(FailureCode) else 422


class JobFailed(ServiceError):
    """Results asked of a failed job: the job's own error and message, with the status
    :func:`failed_job_status` gives it."""

    code, title = "job-failed", "The job failed"

    def __init__(self, detail: str, error: dict[str, Any] | None) -> None:
        super().__init__(detail, (error or {}).get("errors", []))
        self.status = failed_job_status(error)


class Unauthorized(ServiceError):
    status, code, title = 401, "unauthorized", "API key required"

    def __init__(self, detail: str) -> None:
        super().__init__(detail, headers={"WWW-Authenticate": 'Bearer realm="pba"'})


class Forbidden(ServiceError):
    status, code, title = 403, "forbidden", "Forbidden"


class Conflict(ServiceError):
    status, code, title = 409, "conflict", "Conflict"


class UnsupportedMediaType(ServiceError):
    status, code, title = 415, "unsupported-media-type", "Unsupported media type"

    def __init__(self, content_type: str) -> None:
        super().__init__(
            f"the request body must be JSON (Content-Type: application/json), not {content_type!r}",
            errors=[
                {
                    "pointer": "",
                    "code": "unsupported_media_type",
                    "message": "the Content-Type header names no JSON media type",
                }
            ],
            headers={"Accept-Post": "application/json"},
        )


class TooManyJobs(ServiceError):
    status, code, title = 429, "too-many-jobs", "Too many queued jobs"


class JobTooLarge(ServiceError):
    status, code, title = 413, "job-too-large", "Job too large"


class CameraTooLarge(ServiceError):
    status, code, title = 413, "camera-too-large", "Camera definition too large"


class StorageQuotaExceeded(ServiceError):
    status, code, title = 413, "storage-quota-exceeded", "Storage quota exceeded"


class NotReady(ServiceError):
    status, code, title = 503, "not-ready", "Service not ready"


def problem_response(
    request: Request,
    status: int,
    title: str,
    detail: str,
    type_uri: str,
    errors: Sequence[dict[str, Any]] = (),
    headers: dict[str, str] | None = None,
) -> JSONResponse:
    """An RFC 7807 response."""
    body: dict[str, Any] = {
        "type": type_uri,
        "title": title,
        "status": status,
        "detail": detail,
        "instance": request.url.path,
    }
    if errors:
        body["errors"] = [json_ready(e) for e in list(errors)[:MAX_ERRORS]]  # never NaN: a 4xx must not become a 500
        if len(errors) > MAX_ERRORS:
            body["detail"] += f" ({len(errors)} problems; the first {MAX_ERRORS} are listed)"
    # nosniff here too: a 500 is sent by Starlette's outermost middleware, past ours
    headers = {"X-Content-Type-Options": "nosniff", **(headers or {})}
    return JSONResponse(body, status_code=status, media_type=PROBLEM_MEDIA_TYPE, headers=headers)


def allowed_methods(request: Request) -> list[str]:
    """Every method the OpenAPI document offers on this path (Starlette's 405 named only the
    first matching route's: ``GET /jobs/{id}`` hid ``DELETE /jobs/{id}``)."""
    methods: set[str] = set()
    for template, operations in request.app.openapi().get("paths", {}).items():
        if re.fullmatch(re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(template)), request.url.path):
            methods |= {m.upper() for m in operations}
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


def install_error_handlers(app: FastAPI) -> None:
    """Register every exception-to-problem mapping of the service."""

    @app.exception_handler(ServiceError)
    async def _service_error(request: Request, exc: ServiceError) -> JSONResponse:
        return problem_response(
            request, exc.status, exc.title, exc.detail, exc.type_uri, exc.errors, exc.headers
        )

    @app.exception_handler(RequestValidationError)
    async def _request_validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errs = list(exc.errors())
        if any(e.get("type") == "json_invalid" for e in errs):
            ctx = next((e.get("ctx") or {} for e in errs if e.get("type") == "json_invalid"), {})
            return problem_response(
                request,
                400,
                "Malformed JSON",
                f"the request body is not valid JSON: {ctx.get('error', 'decode error')}",
                problem_type("malformed-json"),
            )
        body_errors = [e for e in errs if e.get("loc", ("",))[0] == "body"]
        return problem_response(
            request,
            422 if body_errors else 400,
            "Invalid input" if body_errors else "Invalid parameter",
            "the request does not match the schema; see errors",
            problem_type("invalid-input" if body_errors else "invalid-parameter"),
            pydantic_errors(errs),
        )

    @app.exception_handler(ValidationError)
    async def _validation(request: Request, exc: ValidationError) -> JSONResponse:
        return problem_response(
            request,
            422,
            "Invalid input",
            "the request does not match the schema; see errors",
            problem_type("invalid-input"),
            pydantic_errors(exc.errors()),
        )

    @app.exception_handler(JobError)
    async def _job_error(request: Request, exc: JobError) -> JSONResponse:
        return problem_response(
            request,
            422,
            "Invalid job",
            str(exc),
            problem_type("invalid-job"),
            job_error_entries(exc, ("inputs", "job")),
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        titles = {404: "Not found", 405: "Method not allowed", 413: "Body too large"}
        headers = dict(getattr(exc, "headers", None) or {})
        if exc.status_code == 405:
            headers["Allow"] = ", ".join(allowed_methods(request))
        return problem_response(
            request,
            exc.status_code,
            titles.get(exc.status_code, "HTTP error"),
            str(exc.detail),
            problem_type(f"http-{exc.status_code}"),
            headers=headers,
        )

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem_response(
            request,
            500,
            "Internal server error",
            "an unexpected error occurred; it has been logged",
            problem_type("internal"),
        )
