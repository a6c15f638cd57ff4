"""MkDocs hooks (mkdocs.yml ``hooks:``): the generated reference pages join every build.

The pages of :mod:`gen_reference` are added as generated files, so they are never committed
and cannot be stale; ``mkdocs build --strict`` then checks their links like any other page.
"""

from __future__ import annotations

import sys
from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
for _path in (ROOT, ROOT / "scripts"):
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

import gen_reference  # noqa: E402


def on_files(files: Files, config) -> Files:
    for rel, text in gen_reference.pages().items():
        files.append(File.generated(config, rel, content=text))
    return files
