"""The located error of the importers: which file, which line, which column.

Every problem an importer finds in a source file is a :class:`SourceProblem` naming the file
(as the user gave it), the 1-based line of the file and the column (the header's name of the
field, else its 1-based position). :class:`SourceError` carries one or more of them. It is a
:class:`solver.errors.JobError` (code ``bad_source_file``) whose problems' ``location`` is
``(file, line, column)`` and whose ``detail`` holds the three by name, so the ``pba job``
command prints them and the service answers them as a 4xx problem document without knowing
any format.
"""

from __future__ import annotations

from dataclasses import dataclass

from solver.errors import JobError, Problem


@dataclass(frozen=True)
class SourceProblem:
    """One problem of a source file: ``line`` 1-based (0: the file as a whole), ``column`` the
    field's header name or 1-based position ("" when the whole line is at fault)."""

    file: str
    line: int
    column: str
    message: str
    code: str = "bad_source_file"

    def __str__(self) -> str:
        where = self.file
        if self.line:
            where += f", line {self.line}"
        if self.column:  # an XML element's path (a/b) in metadata files, a header's column elsewhere
            where += f", {'element' if '/' in self.column else 'column'} {self.column}"
        return f"{where}: {self.message}"

    def to_problem(self) -> Problem:
        return Problem(
            self.code,
            str(self),
            (self.file, self.line, self.column),
            {"file": self.file, "line": self.line, "column": self.column},
        )


class SourceError(JobError):
    """One or more located problems of source files."""

    def __init__(self, problems: list[SourceProblem] | SourceProblem):
        self.source_problems = [problems] if isinstance(problems, SourceProblem) else list(problems)
        super().__init__([p.to_problem() for p in self.source_problems])


def fail(file: str, line: int, column: str | int, message: str, code: str = "bad_source_file") -> SourceError:
    """A SourceError with one problem (to ``raise``)."""
    return SourceError(SourceProblem(file, line, str(column), message, code))
