"""Routers, one module per resource; :data:`service.app.ROUTER_MODULES` lists them.

Each module exposes ``router`` (an ``APIRouter`` with a prefix and a tag). Routers that read
JSON bodies use :class:`StrictJSONRoute`, which refuses ``NaN``/``Infinity`` (not JSON).
"""

from __future__ import annotations

import json
from typing import Any, Callable, Coroutine

from fastapi import Request, Response
from fastapi.routing import APIRoute


def _reject_constant(name: str) -> Any:
    raise json.JSONDecodeError(f"{name} is not valid JSON", name, 0)


class StrictJSONRequest(Request):
    """A request whose JSON body may not contain NaN, Infinity or -Infinity."""

    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            body = await self.body()
            self._json = json.loads(body, parse_constant=_reject_constant)
        return self._json


class StrictJSONRoute(APIRoute):
    """Route class parsing bodies with :class:`StrictJSONRequest`."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def strict_handler(request: Request) -> Response:
            return await handler(StrictJSONRequest(request.scope, request.receive))

        return strict_handler
