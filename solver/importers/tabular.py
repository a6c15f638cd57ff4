"""Reading delimited text tables: the part every importer shares.

A table is UTF-8 text (a byte-order mark is dropped), one record a line. Lines whose first
non-blank character is ``#`` are comments; a comment of the form ``# key: value`` is kept as
metadata (e.g. ``# time_scale: GPS``). Blank lines are skipped. The delimiter is a comma, a
semicolon or a tab (sniffed from the header line: the one of the three it holds most), and
fields may be double-quoted. A header names the columns; names are matched without case and
surrounding blanks, through each format's aliases, and a caller may map its own names onto a
format's names (``{"E": "x", "N": "y"}``).

Numbers use a point as the decimal separator (``1.5``, ``-2e3``); a comma decimal separator
("1,5" from a spreadsheet in a Portuguese locale) is refused with a located error rather than
silently read as two fields.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

from solver.importers.errors import SourceError, SourceProblem, fail

DELIMITERS = (",", ";", "\t")
MAX_ROWS = 1_000_000
MAX_COLUMNS = 1000


@dataclass
class Table:
    """A parsed table: the header (canonical names), rows with their file line numbers, and
    the ``# key: value`` metadata of its comments (keys lower-case)."""

    file: str
    header: list[str]
    raw_header: list[str]
    rows: list[tuple[int, list[str]]]
    metadata: dict[str, str] = field(default_factory=dict)
    header_line: int = 0
    positions: dict[str, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.positions = {name: i for i, name in reversed(list(enumerate(self.header)))}

    def column_name(self, index: int) -> str:
        """The name the user wrote for column ``index`` (for messages)."""
        return self.raw_header[index] if index < len(self.raw_header) else str(index + 1)


def decode(data: bytes | str, file: str) -> str:
    """Text of a source file (UTF-8, BOM dropped), or a located error."""
    if isinstance(data, str):
        return data.lstrip("\ufeff")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise fail(file, line, "", "not UTF-8 text") from None


def lines_of(text: str) -> Iterator[tuple[int, str]]:
    """(1-based line number, line without its end) of every line."""
    for n, line in enumerate(text.splitlines(), start=1):
        yield n, line


def comment_metadata(line: str) -> tuple[str, str] | None:
    """(key, value) of a ``# key: value`` comment, else None."""
    body = line.strip().lstrip("#").strip()
    if ":" not in body:
        return None
    key, value = body.split(":", 1)
    key = key.strip().lower().replace(" ", "_")
    if not key or " " in key.strip():
        return None
    return key, value.strip()


def sniff_delimiter(line: str) -> str:
    """The delimiter of a header line: the one of ``DELIMITERS`` it holds most (comma on ties)."""
    counts = {d: line.count(d) for d in DELIMITERS}
    best = max(DELIMITERS, key=lambda d: (counts[d], d == ","))
    return best if counts[best] else ","


def read_table(
    data: bytes | str,
    file: str,
    aliases: Mapping[str, Sequence[str]],
    required: Sequence[str],
    columns: Mapping[str, str] | None = None,
) -> Table:
    """Parse a table whose header names (after ``columns``, the caller's map from its own
    names to canonical ones, then ``aliases``: canonical name -> accepted spellings) must
    include every ``required`` canonical name. Unknown columns are kept under their own
    (lower-case) names."""
    text = decode(data, file)
    metadata: dict[str, str] = {}
    header: list[str] | None = None
    raw: list[str] = []
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    delimiter = ","
    for n, line in lines_of(text):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            kv = comment_metadata(stripped)
            if kv and header is None:
                metadata[kv[0]] = kv[1]
            continue
        if header is None:
            delimiter = sniff_delimiter(line)
            raw = [h.strip() for h in _fields(line, delimiter, file, n)]
            if len(raw) > MAX_COLUMNS:
                raise fail(file, n, "", f"{len(raw)} columns; at most {MAX_COLUMNS}", "too_many_columns")
            header = canonical_header(raw, aliases, columns or {}, file, n)
            header_line = n
            continue
        fields = _fields(line, delimiter, file, n)
        rows.append((n, [f.strip() for f in fields]))
        if len(rows) > MAX_ROWS:
            raise fail(file, n, "", f"more than {MAX_ROWS} rows")
    if header is None:
        raise fail(file, 0, "", "the file has no header line (and no rows)")
    missing = [r for r in required if r not in header]
    if missing:
        known = ", ".join(raw)
        raise fail(
            file,
            header_line,
            "",
            f"the header has no column for {', '.join(missing)} (it has: {known}); name the "
            "columns as the format says or map them (column names are configurable)",
            "unrecognised_header",
        )
    table = Table(file, header, raw, rows, metadata, header_line)
    for n, fields in rows:
        if len(fields) != len(header):
            raise fail(
                file, n, "", f"{len(fields)} fields where the header has {len(header)} (delimiter {delimiter!r})"
            )
    return table


def _fields(line: str, delimiter: str, file: str, n: int) -> list[str]:
    """The fields of one line, or a located error (a field over the csv module's limit, a NUL)."""
    try:
        return next(csv.reader([line], delimiter=delimiter))
    except csv.Error as exc:
        raise fail(file, n, "", f"not a readable table line: {exc}", "unreadable_line") from None


def canonical_header(
    raw: Sequence[str], aliases: Mapping[str, Sequence[str]], columns: Mapping[str, str], file: str, line: int
) -> list[str]:
    """Canonical names of a header's columns; a located error when two columns mean the same."""
    user = {k.strip().lower(): v for k, v in columns.items()}
    spelled = {s.lower(): name for name, spellings in aliases.items() for s in (name, *spellings)}
    out: list[str] = []
    seen: set[str] = set()
    for i, name in enumerate(raw):
        key = name.lower()
        canon = user.get(key) or spelled.get(key) or key
        if canon in seen and canon:
            raise fail(file, line, name or str(i + 1), f"a second column for {canon!r}")
        seen.add(canon)
        out.append(canon)
    return out


def number(table: Table, line: int, fields: list[str], name: str, *, default: float | None = None) -> float:
    """The finite number in column ``name`` of a row (``default`` when the column is absent
    or the field empty and a default is given), or a located error."""
    i = table.positions.get(name)
    if i is None:
        if default is None:
            raise fail(table.file, line, name, "missing")
        return default
    return parse_number(fields[i], table.file, line, table.column_name(i), default)


def parse_number(text: str, file: str, line: int, column: str, default: float | None = None) -> float:
    """A finite float from ``text`` or a located error naming it."""
    if text == "":
        if default is not None:
            return default
        raise fail(file, line, column, "empty (a number is needed)")
    try:
        value = float(text)
    except ValueError:
        hint = " (use a point as the decimal separator)" if "," in text else ""
        raise fail(file, line, column, f"{text!r} is not a number{hint}") from None
    if not math.isfinite(value):
        raise fail(file, line, column, f"{text!r} is not a finite number")
    return value


def text_field(table: Table, line: int, fields: list[str], name: str, default: str | None = None) -> str:
    """The non-empty text in column ``name`` (``default`` when absent or empty, if given)."""
    i = table.positions.get(name)
    if i is not None:
        value = fields[i]
        if value:
            return value
    if default is not None:
        return default
    raise fail(table.file, line, name, "empty (a value is needed)")


def collect(problems: list[SourceProblem]) -> None:
    """Raise every collected problem at once (nothing when the list is empty)."""
    if problems:
        raise SourceError(problems)


def write_rows(header: Sequence[str], rows: Sequence[Sequence[object]], comments: Sequence[str] = ()) -> str:
    """CSV text (comma, ``\\n`` line ends, numbers by ``repr``: round-trip exact)."""
    buf = io.StringIO()
    for c in comments:
        buf.write(f"# {c}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow([fmt(v) for v in r])
    return buf.getvalue()


def fmt(v: object) -> str:
    """A field: floats by ``repr`` (shortest text that reads back to the same float)."""
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)
