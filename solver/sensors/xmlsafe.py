"""XML of vendors' metadata, read safely: no DTD, no entity expansion, no external entities
(defusedxml refuses them: a billion-laughs or an external-entity file is an error, never
expanded), limits checked while parsing, and typed accessors whose errors name the file and
the element.

The limits (:data:`MAX_BYTES`, :data:`MAX_DEPTH`, :data:`MAX_ELEMENTS`,
:data:`MAX_ATTRIBUTES`, :data:`MAX_ATTRIBUTES_TOTAL`, :data:`MAX_TAG_BYTES`) are checked as the
document streams through the parser (64 kB at a time, a file read in such chunks): a hostile
file is refused at the first element past a limit, before the rest is parsed or the tree built.
The length of a tag is watched on the bytes before they reach expat, which hands over an
element only once its start tag is complete (a start tag of a million attributes would be
buffered and re-scanned whole: 10 s and 300 MB before the attribute count could be seen). The largest
vendor file of the tests (a SPOT 5 DIMAP) has 9,638 elements, 10 levels and 2 attributes per
element; a WorldView-3 XML is about 2 MB.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as StdET
from collections.abc import Iterable, Iterator
from pathlib import Path

import defusedxml.ElementTree as SafeET
from defusedxml.common import DefusedXmlException

from solver.sensors.errors import MetadataError

MAX_BYTES = 32 * 2**20  # larger than any vendor metadata file (a WorldView-3 XML is ~2 MB)
MAX_DEPTH = 64  # nesting of elements (vendor metadata: about a dozen)
MAX_ELEMENTS = 200_000
MAX_ATTRIBUTES = 64  # of one element
MAX_ATTRIBUTES_TOTAL = 500_000
MAX_TAG_BYTES = 2**20  # one tag (a start tag with its attributes), read before the parser sees it whole
CHUNK_BYTES = 64 * 2**10


class _OverLimit(Exception):
    """A limit passed while parsing: the element's tag and what was passed."""

    def __init__(self, tag: str, message: str):
        super().__init__(message)
        self.tag, self.message = tag, message


class _CountingBuilder(StdET.TreeBuilder):
    """ElementTree's tree builder, counting depth, elements and attributes as they start."""

    def __init__(self) -> None:
        super().__init__()
        self.depth = self.elements = self.attributes = 0

    def start(self, tag: str, attrs: dict[str, str]) -> StdET.Element:
        self.depth += 1
        self.elements += 1
        self.attributes += len(attrs)
        if self.depth > MAX_DEPTH:
            raise _OverLimit(tag, f"elements nested deeper than {MAX_DEPTH} levels")
        if self.elements > MAX_ELEMENTS:
            raise _OverLimit(tag, f"more than {MAX_ELEMENTS} elements")
        if len(attrs) > MAX_ATTRIBUTES:
            raise _OverLimit(tag, f"{len(attrs)} attributes on one element (at most {MAX_ATTRIBUTES})")
        if self.attributes > MAX_ATTRIBUTES_TOTAL:
            raise _OverLimit(tag, f"more than {MAX_ATTRIBUTES_TOTAL} attributes")
        return super().start(tag, attrs)

    def end(self, tag: str) -> StdET.Element:
        self.depth -= 1
        return super().end(tag)


def read_bytes(path: Path, shown: str) -> bytes:
    """The file's bytes (MetadataError when missing, unreadable or larger than :data:`MAX_BYTES`)."""
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise MetadataError(shown, "", f"{size} bytes: larger than a metadata file ({MAX_BYTES} bytes at most)")
        return path.read_bytes()
    except OSError as exc:
        raise MetadataError(shown, "", f"cannot read it: {exc.strerror or exc}") from None


def _too_large(shown: str, size: int) -> MetadataError:
    return MetadataError(shown, "", f"{size} bytes: larger than a metadata file ({MAX_BYTES} bytes at most)")


def parse(data: bytes | Iterable[bytes], shown: str) -> StdET.Element:
    """The root element of an XML document (its bytes, or its chunks as they are read); DTDs
    and entities are refused, and the limits of the module docstring are checked as it streams
    (MetadataError naming the element at which one was passed, and its line)."""
    chunks: Iterable[bytes] = (data[i : i + CHUNK_BYTES] for i in range(0, len(data), CHUNK_BYTES)) if isinstance(data, bytes) else data
    builder = _CountingBuilder()
    parser = SafeET.DefusedXMLParser(target=builder, forbid_dtd=True, forbid_entities=True, forbid_external=True)
    size = 0
    open_tag: int | None = None  # where the last '<' not yet followed by a '>' is
    head = b""
    try:
        for chunk in chunks:
            lt, gt = chunk.rfind(b"<"), chunk.rfind(b">")
            if lt > gt:
                open_tag, head = size + lt, chunk[lt : lt + 80]
            elif gt >= 0:
                open_tag = None
            size += len(chunk)
            if size > MAX_BYTES:
                raise _too_large(shown, size)
            if open_tag is not None and size - open_tag > MAX_TAG_BYTES:
                name = head[1:].split(None, 1)[0].decode("utf-8", "replace") if head[1:].strip() else ""
                raise _OverLimit(name, f"a tag longer than {MAX_TAG_BYTES} bytes (from byte {open_tag})")
            parser.feed(chunk)
        return parser.close()
    except _OverLimit as exc:
        line = getattr(getattr(parser, "parser", None), "CurrentLineNumber", 0)
        raise MetadataError(shown, exc.tag, f"refused: {exc.message} (line {line}); vendor metadata has far fewer") from None
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

    def check_counts(self, prefix: str = "NUM", maximum: int = MAX_ELEMENTS) -> None:
        """Every element below this one whose tag starts with ``prefix`` (a vendor's counts:
        ``NUMROWS``, ``NUMPOINTS``, ``NUMLISTS``...) and whose text is a number must be a whole
        number from 0 to ``maximum``, read or not: a negative or absurd count is refused naming
        the element (the file is damaged or forged)."""
        stack = [(self.element, self.path)]
        while stack:
            element, path = stack.pop()
            for child in element:
                where = f"{path}/{child.tag}"
                if isinstance(child.tag, str) and child.tag.startswith(prefix) and len(child) == 0:
                    text = (child.text or "").strip()
                    try:
                        value = float(text)
                    except ValueError:
                        value = None
                    if value is not None and not (math.isfinite(value) and value == int(value) and 0 <= value <= maximum):
                        raise MetadataError(self.file, where, f"{text[:40]!r}: a count must be a whole number from 0 to {maximum}")
                stack.append((child, where))

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


def _file_chunks(path: Path, shown: str) -> Iterator[bytes]:
    try:
        with open(path, "rb") as f:
            while chunk := f.read(CHUNK_BYTES):
                yield chunk
    except OSError as exc:
        raise MetadataError(shown, "", f"cannot read it: {exc.strerror or exc}") from None


def load(path: Path, shown: str, data: bytes | None = None) -> Node:
    """The parsed root of an XML file (streamed from it, or of its ``data``) as a :class:`Node`."""
    if data is not None and len(data) > MAX_BYTES:
        raise _too_large(shown, len(data))
    if data is None:
        try:
            if path.stat().st_size > MAX_BYTES:
                raise _too_large(shown, path.stat().st_size)
        except OSError as exc:
            raise MetadataError(shown, "", f"cannot read it: {exc.strerror or exc}") from None
    root = parse(_file_chunks(path, shown) if data is None else data, shown)
    return Node(root, root.tag, shown)
