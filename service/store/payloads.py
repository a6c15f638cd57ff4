"""How job payloads (execute inputs, reports) are stored: zlib-compressed UTF-8 JSON.

A report is mostly per-observation rows of numbers in repeated keys, which deflate shrinks
several-fold (docs/how-to/lab-server.md "Retention" gives a measured ratio). Rows written before revision 0003
hold plain JSON text in the old columns; :func:`unpack` reads either form.
"""

from __future__ import annotations

import zlib

LEVEL = 6  # zlib's default: most of level 9's ratio at a fraction of its time


def pack(text: str) -> bytes:
    """Compressed bytes of a JSON text."""
    return zlib.compress(text.encode("utf-8"), LEVEL)


def unpack(packed: bytes | None, plain: str | None) -> str | None:
    """The JSON text of a payload: the compressed column when set, else the old plain one."""
    if packed is not None:
        return zlib.decompress(packed).decode("utf-8")
    return plain
