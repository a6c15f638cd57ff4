"""Print the OpenAPI document of the app as YAML (``make openapi`` writes openapi.yaml)."""

from __future__ import annotations

import sys
from typing import Any

import yaml

from service.app import create_app
from service.settings import Settings


def openapi_document() -> dict[str, Any]:
    """The app's OpenAPI document, independent of the environment's settings."""
    return create_app(Settings(_env_file=None)).openapi()  # type: ignore[call-arg]


def render() -> str:
    """The document as YAML text (stable key order)."""
    return yaml.safe_dump(openapi_document(), sort_keys=False, allow_unicode=True, width=100)


if __name__ == "__main__":
    sys.stdout.write(render())
