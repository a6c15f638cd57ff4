"""ASGI middlewares: request body size limit (413 problem), URL text check (400 problem for a
NUL or control character in the path or query), services context, access log, security headers
on every response."""

from __future__ import annotations

import json
import logging
import re
import time
from typing import Any
from urllib.parse import parse_qsl

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.deps import reset_current_services, set_current_services
from service.errors import PROBLEM_MEDIA_TYPE, problem_type

log = logging.getLogger("pba.http")


class BodyLimitMiddleware:
    """Refuse request bodies over ``max_bytes`` with a 413 problem document, before the app
    sees them: by the declared Content-Length (the body then streams through, so a big upload
    is not held in memory here), or counted while reading a chunked body."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _refuse(self, scope: Scope, send: Send) -> None:
        body = json.dumps(
            {
                "type": problem_type("body-too-large"),
                "title": "Request body too large",
                "status": 413,
                "detail": f"the request body exceeds the limit of {self.max_bytes} bytes",
                "instance": scope.get("path", ""),
            }
        ).encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [
                    (b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                    (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] in ("GET", "HEAD", "OPTIONS", "DELETE"):
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length")
        if declared is not None:
            try:
                length = int(declared)
            except ValueError:
                length = -1
            if length > self.max_bytes:
                await self._refuse(scope, send)
                return
            if length >= 0:  # the server frames the body by its length: streamed, never held here
                await self.app(scope, self._bounded(receive), send)
                return
        # no usable length (chunked): read (and count) the whole body, then replay it to the app
        chunks: list[bytes] = []
        total = 0
        more = True
        while more:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            chunk = message.get("body", b"")
            total += len(chunk)
            if total > self.max_bytes:
                await self._refuse(scope, send)
                return
            chunks.append(chunk)
            more = message.get("more_body", False)
        body = b"".join(chunks)
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)

    def _bounded(self, receive: Receive) -> Receive:
        """``receive`` passing the body through as it comes, a disconnect past ``max_bytes``
        (a guard: the server does not deliver more than the declared length)."""
        total = 0

        async def bounded() -> Message:
            nonlocal total
            message = await receive()
            if message["type"] == "http.request":
                total += len(message.get("body", b""))
                if total > self.max_bytes:
                    return {"type": "http.disconnect"}
            return message

        return bounded


def _has_control(text: str) -> bool:
    """Whether ``text`` holds a NUL or another control character (C0 or DEL)."""
    return any(ord(c) < 0x20 or ord(c) == 0x7F for c in text)


class UrlTextMiddleware:
    """Refuse a request whose URL path or query holds a NUL or control character (once
    percent-decoded) with a 400 problem naming the parameter (``/path/jobId``,
    ``/query/name``), before any route, the store or the file system sees it. (PostgreSQL
    refuses NUL in text, which would otherwise be a 500; no name the server knows holds
    one.)"""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    @staticmethod
    def _templates(app: Any) -> list[tuple[re.Pattern[str], list[str]]]:
        """The OpenAPI path templates as patterns (those with the fewest parameters first)."""
        cached = getattr(app.state, "url_templates", None) if hasattr(app, "state") else None
        if cached is not None:
            return cached
        out = []
        for template in app.openapi().get("paths", {}) if hasattr(app, "openapi") else ():
            names = re.findall(r"\{([^}/]+)\}", template)
            parts = re.split(r"\{[^}/]+\}", template)
            pattern = "".join(re.escape(p) + ("([^/]+)" if i < len(names) else "") for i, p in enumerate(parts))
            out.append((re.compile(pattern), names))
        out.sort(key=lambda t: len(t[1]))
        if hasattr(app, "state"):
            app.state.url_templates = out
        return out

    @classmethod
    def _pointers(cls, scope: Scope) -> list[str]:
        out: list[str] = []
        path = scope.get("path", "")
        if _has_control(path):
            for pattern, names in cls._templates(scope.get("app")):
                m = pattern.fullmatch(path)
                if m is not None:
                    out += [f"/path/{n}" for n, v in zip(names, m.groups()) if _has_control(v)]
                    if out:
                        break
            if not out:
                out.append("/path")
        query = scope.get("query_string", b"").decode("latin-1")
        for name, value in parse_qsl(query, keep_blank_values=True):
            if _has_control(name) or _has_control(value):
                out.append("/query/" + ("" if _has_control(name) else name))
        return out

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        pointers = self._pointers(scope)
        if not pointers:
            await self.app(scope, receive, send)
            return
        message = "a NUL or control character (percent-encoded or not) is not allowed here"
        body = json.dumps(
            {
                "type": problem_type("invalid-parameter"),
                "title": "Invalid parameter",
                "status": 400,
                "detail": "the URL holds a NUL or control character",
                "errors": [{"pointer": p, "code": "control_character", "message": message} for p in pointers],
            }
        ).encode()
        await send(
            {
                "type": "http.response.start",
                "status": 400,
                "headers": [
                    (b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})


class ServicesContextMiddleware:
    """Binds the app's services to the request's context (for :func:`get_job_for_user`)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        app: Any = scope.get("app")
        services = getattr(getattr(app, "state", None), "services", None)
        token = set_current_services(services)
        try:
            await self.app(scope, receive, send)
        finally:
            reset_current_services(token)


class AccessLogMiddleware:
    """One structured log line per request (method, path, status, duration)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        status = 500

        async def send_logged(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_logged)
        finally:
            log.info(
                "%s %s %d",
                scope["method"],
                scope["path"],
                status,
                extra={
                    "method": scope["method"],
                    "path": scope["path"],
                    "status": status,
                    "duration_ms": round((time.perf_counter() - t0) * 1000, 1),
                },
            )


class SecurityHeadersMiddleware:
    """Adds ``X-Content-Type-Options: nosniff`` to every HTTP response (JSON, problem
    documents, CSV, static files, the web page, and the 413 refusals of the body limit), so a
    browser never reads a response as another type than the one declared."""

    HEADERS: tuple[tuple[bytes, bytes], ...] = ((b"x-content-type-options", b"nosniff"),)

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers") or [])
                present = {name.lower() for name, _ in headers}
                headers += [(k, v) for k, v in self.HEADERS if k not in present]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)
