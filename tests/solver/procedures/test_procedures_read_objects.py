"""The procedures steer by a typed solution (solver/report/solution.py), not by the report: no
module of solver/procedures/ reads a dictionary by a string key (``x["key"]``, ``x.get("key")``;
writing its own entries of the report is allowed), and none reads the job's options but through
the settings objects (solver/schema/settings.py). Each check has its teeth test."""

from __future__ import annotations

import ast
from pathlib import Path

from solver.schema.job import SolverOptions

PROCEDURES = Path(__file__).resolve().parents[3] / "solver" / "procedures"


def string_key_reads(source: str) -> list[int]:
    """Lines of ``source`` that read a mapping by a string constant."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load):
            if isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str):
                out.append(node.lineno)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in ("get", "setdefault", "pop"):
            if node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                out.append(node.lineno)
    return out


def option_reads(source: str) -> list[int]:
    """Lines of ``source`` that read a field of a job's ``options`` directly (``<x>.options.<field>``)."""
    fields = set(SolverOptions.model_fields)
    return [
        node.lineno
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Attribute) and node.attr in fields
        and isinstance(node.value, ast.Attribute) and node.value.attr == "options"
    ]


def test_the_procedures_read_no_report_dict() -> None:
    reads = {f.name: string_key_reads(f.read_text()) for f in sorted(PROCEDURES.glob("*.py"))}
    assert {k: v for k, v in reads.items() if v} == {}


def test_the_procedures_read_options_through_the_settings() -> None:
    reads = {f.name: option_reads(f.read_text()) for f in sorted(PROCEDURES.glob("*.py"))}
    assert {k: v for k, v in reads.items() if v} == {}


def test_the_scans_have_teeth() -> None:
    source = (
        'x = report["quality"]\n'          # 1: a read
        'y = rep.get("images")\n'          # 2: a read
        'report["warnings"] = []\n'         # 3: a write, allowed
        'z = rows[0]\n'                     # 4: not a string key
        'w = job.options.parsimony\n'       # 5: an option read directly
        'v = job.options.model_copy()\n'    # 6: a copy, not a field
    )
    assert string_key_reads(source) == [1, 2]
    assert option_reads(source) == [5]
