"""XML of vendors' metadata, read safely: no DTD, no entity expansion, no external entities
(defusedxml refuses them: a billion-laughs or an external-entity file is an error, never
expanded), a size limit, and typed accessors whose errors name the file and the element.
"""

from __future__ import annotations

import xml.etree.ElementTree as StdET
from pathlib import Path

import defusedxml.ElementTree as SafeET
from defusedxml.common import DefusedXmlException

from solver.sensors.errors import MetadataError

MAX_BYTES = 64 * 2**20  # larger than any vendor metadata file (a WorldView-3 XML is ~2 MB)


def read_bytes(path: Path, shown: str) -> bytes:
    """The file's bytes (MetadataError when missing, unreadable or larger than :data:`MAX_BYTES`)."""
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise MetadataError(shown, "", f"{size} bytes: larger than a metadata file ({MAX_BYTES} bytes at most)")
        return path.read_bytes()
    except OSError as exc:
        raise MetadataError(shown, "", f"cannot read it: {exc.strerror or exc}") from None


def parse(data: bytes, shown: str) -> StdET.Element:
    """The root element of an XML document; DTDs and entities are refused."""
    try:
        return SafeET.fromstring(data, forbid_dtd=True, forbid_entities=True, forbid_external=True)
    except DefusedXmlException as exc:
        raise MetadataError(shown, "", f"refused: the XML declares a DTD or entities ({type(exc).__name__}); "
                            "vendor metadata has none") from None
    except StdET.ParseError as exc:
        line, col = getattr(exc, "position", (0, 0))
        raise MetadataError(shown, "", f"not well-formed XML (line {line}, column {col}): truncated or damaged") from None


class Node:
    """An element with its path, for located errors: ``node.child("EPH").number("NUMPOINTS")``."""

    def __init__(self, element: StdET.Element, path: str, file: str):
        self.element, self.path, self.file = element, path, file

    def error(self, message: str, child: str = "") -> MetadataError:
        return MetadataError(self.file, f"{self.path}/{child}" if child else self.path, message)

    def find(self, tag: str) -> "Node | None":
        e = self.element.find(tag)
        return None if e is None else Node(e, f"{self.path}/{tag}", self.file)

    def child(self, tag: str) -> "Node":
        n = self.find(tag)
        if n is None:
            raise self.error("missing", tag)
        return n

    def children(self, tag: str) -> list["Node"]:
        return [Node(e, f"{self.path}/{tag}", self.file) for e in self.element.findall(tag)]

    def text(self, tag: str) -> str:
        t = (self.child(tag).element.text or "").strip()
        if not t:
            raise self.error("empty", tag)
        return t

    def number(self, tag: str) -> float:
        t = self.text(tag)
        try:
            v = float(t)
        except ValueError:
            raise self.error(f"not a number: {t[:40]!r}", tag) from None
        if v != v or v in (float("inf"), float("-inf")):
            raise self.error(f"not a finite number: {t[:40]!r}", tag)
        return v

    def integer(self, tag: str) -> int:
        v = self.number(tag)
        if v != int(v):
            raise self.error(f"not an integer: {v}", tag)
        return int(v)

    def numbers(self, tag: str | None = None, count: int | None = None) -> list[float]:
        """The whitespace-separated numbers of a child (or of this element when ``tag`` is None)."""
        node = self if tag is None else self.child(tag)
        words = (node.element.text or "").split()
        try:
            vals = [float(w) for w in words]
        except ValueError:
            raise node.error(f"not a list of numbers: {(node.element.text or '').strip()[:40]!r}") from None
        if count is not None and len(vals) != count:
            raise node.error(f"{count} numbers expected, {len(vals)} found")
        if any(v != v or abs(v) == float("inf") for v in vals):
            raise node.error("non-finite number")
        return vals


def load(path: Path, shown: str, data: bytes | None = None) -> Node:
    """The parsed root of an XML file (or of its ``data``) as a :class:`Node`."""
    if data is not None and len(data) > MAX_BYTES:
        raise MetadataError(shown, "", f"{len(data)} bytes: larger than a metadata file ({MAX_BYTES} bytes at most)")
    root = parse(read_bytes(path, shown) if data is None else data, shown)
    return Node(root, root.tag, shown)
