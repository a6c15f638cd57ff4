"""The web page: ``/ui`` (plain HTML, CSS and JavaScript from ``service/static/ui/``, no build
step) and the example job documents it offers (``/ui/examples``, from ``examples/*.json``).

The page talks to the public API only (validate, execute, jobs, events, results, plots); it
keeps an API key in the browser's sessionStorage and sends it as ``X-API-Key`` (``?api_key=``
for EventSource). None of these routes needs a key, and none is part of the OpenAPI document.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

from fastapi import APIRouter
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse

from service.deps import BaseUrl
from service.errors import NotFound

router = APIRouter(tags=["ui"], include_in_schema=False)

STATIC_DIR = Path(__file__).resolve().parents[1] / "static" / "ui"
EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"
ASSET_TYPES = {
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
    ".png": "image/png",
}
# the page may load its own assets and talk to this server; nothing else
PAGE_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; img-src 'self' blob: data:; script-src 'self'; "
        "style-src 'self'; connect-src 'self'; object-src 'none'; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-cache",
}


def _html(name: str, base: str) -> HTMLResponse:
    """A page of service/static/ui/ with its links resolving against the server's base URL."""
    html = (STATIC_DIR / name).read_text(encoding="utf-8")
    base_attr = base.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
    return HTMLResponse(html.replace("{{BASE}}", base_attr), headers=PAGE_HEADERS)


@router.get("/ui", response_class=HTMLResponse)
def page(base: BaseUrl) -> HTMLResponse:
    """The web page."""
    return _html("index.html", base)


@router.get("/ui/admin", response_class=HTMLResponse)
def admin_page(base: BaseUrl) -> HTMLResponse:
    """The admin page (its data, ``GET /admin/overview``, answers admins only)."""
    return _html("admin.html", base)


@router.get("/ui/assets/{name}")
def asset(name: str) -> FileResponse:
    """A static file of the page (only files that exist directly in service/static/ui/)."""
    path = STATIC_DIR / name
    if (
        "/" in name
        or "\\" in name
        or name.startswith(".")
        or path.suffix not in ASSET_TYPES
        or not path.is_file()
    ):
        raise NotFound(f"there is no asset {name!r}")
    return FileResponse(
        path,
        media_type=ASSET_TYPES[path.suffix],
        headers={"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"},
    )


class _Examples:
    """The example jobs in ``examples/`` (not the ``*.truth.json`` files), re-read on change."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.lock = threading.Lock()
        self._stamp: tuple[tuple[str, float], ...] | None = None
        self._list: list[dict[str, Any]] = []

    def files(self) -> dict[str, Path]:
        if not self.directory.is_dir():
            return {}
        return {
            p.stem: p
            for p in sorted(self.directory.glob("*.json"))
            if not p.name.endswith(".truth.json") and p.is_file()
        }

    def listing(self) -> list[dict[str, Any]]:
        files = self.files()
        stamp = tuple((name, p.stat().st_mtime) for name, p in files.items())
        with self.lock:
            if stamp != self._stamp:
                self._list = [self._describe(name, p) for name, p in files.items()]
                self._stamp = stamp
            return self._list

    @staticmethod
    def _describe(name: str, path: Path) -> dict[str, Any]:
        entry: dict[str, Any] = {"name": name, "bytes": path.stat().st_size}
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {**entry, "title": name}
        counts = {k: len(doc.get(k) or []) for k in ("images", "points", "observations")}
        return {**entry, "title": str(doc.get("name") or name), **counts}


_examples = _Examples(EXAMPLES_DIR)


@router.get("/ui/examples")
def list_examples() -> JSONResponse:
    """The example job documents: name, title, size and counts."""
    return JSONResponse({"examples": _examples.listing()})


@router.get("/ui/examples/{name}")
def get_example(name: str) -> FileResponse:
    """One example job document (``examples/<name>.json``)."""
    path = _examples.files().get(name.removesuffix(".json"))
    if path is None:
        raise NotFound(f"there is no example {name!r}")
    return FileResponse(path, media_type="application/json")
