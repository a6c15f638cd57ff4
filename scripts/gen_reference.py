"""Reference pages of the documentation site, generated from the code.

Each page is built from the object the program itself uses, so it cannot drift from it:

- ``reference/job.md``: the job document, from the pydantic JSON Schema of ``solver.schema.job.Job``
  (every model and field, with its type, limits, default, unit and description);
- ``reference/cli.md``: the ``pba`` command line, walking the argparse parsers of ``service.cli``;
- ``reference/http-api.md``: the HTTP API, from ``openapi.yaml`` (kept in sync with the app by a test);
- ``reference/settings.md``: the server's ``PBA_*`` settings, from ``service.settings.Settings``;
- ``reference/platform-models.md``: the platform models of the registry (``pba models``);
- ``reference/report-keys.md``: every key of the example jobs' reports (the report contract itself,
  docs/report-contract.md, is written by hand; a test checks it names every one of these keys).

The MkDocs hook (scripts/mkdocs_hooks.py) adds these pages to every build; tests/test_docs.py
generates them into a temporary folder and checks that every schema field, CLI flag, endpoint
and setting has its entry. By hand: ``python scripts/gen_reference.py OUTDIR``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]

# units read from a field name's suffix (the project's naming rule: units are in the names)
UNIT_SUFFIXES = (
    ("_m_s", "m/s"),
    ("_mm", "mm"),
    ("_px", "px"),
    ("_deg", "deg"),
    ("_s", "s"),
    ("_m", "m"),
    ("_mb", "MB (10^6 bytes)"),
    ("_bytes", "bytes"),
    ("_days", "days"),
)


# The unit (and frame) of the job's numeric fields whose names state none; "1": a dimensionless
# number, "count": a number of things. tests/test_docs.py fails when a numeric field has neither a
# unit in its name nor an entry here.
FIELD_UNITS = {
    "DemGrid.transform": "the grid CRS's units (a, b, d, e per cell; c, f at the first cell's corner)",
    "DemGrid.rows": "cells",
    "DemGrid.columns": "cells",
    "DemHeights.loss_scale": "sigmas of a DEM height",
    "BiasPrior.value": "px (a0, b0) or px/px (the others)",
    "BiasPrior.sigma": "as `value`",
    "BlunderDetection.alpha0": "1 (probability)",
    "BlunderDetection.beta": "1 (probability)",
    "BlunderDetection.max_rejections": "count",
    "BlunderDetection.separability": "1 (correlation)",
    "Camera.lines": "count (px)",
    "Camera.columns": "count (px)",
    "Camera.iop": "each parameter's unit ([Models](../models.md) section 8: x0, y0, df, a0, b0 mm; k1 mm^-2; k2 mm^-4; sy, a1, b1 1; delta rad)",
    "CameraRef.version": "count",
    "Chip.first_column": "px (image column of the chip's first detector)",
    "Chip.columns": "count (px)",
    "EphemerisOptions.nodes": "count",
    "FittedImageLine.a": "px/px",
    "FittedImageLine.b": "px (image line or column at 0)",
    "FittedImageLine.sigma_a": "px/px",
    "FittedImageLine.sigma_b": "px",
    "FittedImageLine.correlation": "1",
    "GroundLine.endpoints": "the job's `crs` axes (as `GroundPoint.coordinates`)",
    "GroundPoint.coordinates": "the point's `crs` (default the job's) axes: x, y (easting, northing m or longitude, latitude deg), z ellipsoidal height m",
    "Image.initial": "each parameter's report unit (`pba models`)",
    "ImageObservation.line": "px (image line; 0 = centre of the first line, grows with time)",
    "ImageObservation.column": "px (image column; 0 = centre of the first column)",
    "IopCovariance.matrix": "products of the IOP parameters' units (as `Camera.iop`)",
    "LineImagePoint.line": "px (as `ImageObservation.line`)",
    "LineImagePoint.column": "px (as `ImageObservation.column`)",
    "ModelOptions.orders": "count (polynomial order of each element)",
    "Parsimony.threshold": "1 (multiple of sigma)",
    "Parsimony.alpha": "1 (probability)",
    "Parsimony.max_steps": "count",
    "PreanalysisOptions.line_points": "count",
    "QualityWarnings.correlation": "1 (correlation)",
    "Rpc.line_off": "px (RPC00B, `pixel_convention`)",
    "Rpc.samp_off": "px (RPC00B, `pixel_convention`)",
    "Rpc.lat_off": "deg (WGS 84 geodetic latitude)",
    "Rpc.long_off": "deg (WGS 84 geodetic longitude)",
    "Rpc.height_off": "m (WGS 84 ellipsoidal height)",
    "Rpc.line_scale": "px",
    "Rpc.samp_scale": "px",
    "Rpc.lat_scale": "deg",
    "Rpc.long_scale": "deg",
    "Rpc.height_scale": "m",
    "Rpc.line_num_coeff": "1 (normalised coordinates, RPC00B term order)",
    "Rpc.line_den_coeff": "1 (normalised coordinates, RPC00B term order)",
    "Rpc.samp_num_coeff": "1 (normalised coordinates, RPC00B term order)",
    "Rpc.samp_den_coeff": "1 (normalised coordinates, RPC00B term order)",
    "Rpc.err_bias": "m",
    "Rpc.err_rand": "m",
    "SelfCalibration.sigmas": "each parameter's unit (as `Camera.iop`)",
    "SelfCalibration.significance_threshold": "1 (multiple of sigma)",
    "SolverOptions.max_iterations": "count",
    "SolverOptions.function_tolerance": "1 (relative cost change)",
    "SolverOptions.parameter_tolerance": "1 (relative step)",
    "SolverOptions.sigma0_apriori": "1 (standard deviation of unit weight)",
    "SolverOptions.alpha": "1 (probability)",
    "SolverOptions.correlation_threshold": "1 (correlation)",
    "SolverOptions.loss_scale": "1 (whitened residual: multiples of its sigma)",
}


def field_unit(model: str, name: str) -> str:
    """The unit of field ``name`` of schema model ``model``: from its name's suffix, else
    :data:`FIELD_UNITS` ('' when neither says)."""
    return unit_of(name) or FIELD_UNITS.get(f"{model}.{name}", "")


def unit_of(name: str) -> str:
    """The unit a field name states by its suffix ('' when it states none)."""
    for suffix, unit in UNIT_SUFFIXES:
        if name.lower().endswith(suffix):
            return unit
    return ""


def _cell(text: Any) -> str:
    """Text fit for one Markdown table cell."""
    s = " ".join(str(text).split())
    return s.replace("|", "\\|")


def _prose(text: str) -> str:
    """A docstring as Markdown: reST roles and double backticks as code spans."""
    text = re.sub(r":(?:mod|class|func|meth|attr|data):`~?([^`]+)`", r"`\1`", text)
    return text.replace("``", "`")


def _code(value: Any) -> str:
    return "`" + json.dumps(value).replace("|", "\\|") + "`"


def _anchor(name: str) -> str:
    return name.lower()


# ---------------------------------------------------------------- the job document ----------
def _schema_type(prop: dict[str, Any]) -> str:
    """A short type of one JSON Schema property, with links to the models it names."""
    if "$ref" in prop:
        name = prop["$ref"].rsplit("/", 1)[1]
        return f"[{name}](#{_anchor(name)})"
    if "const" in prop:
        return f"constant {_code(prop['const'])}"
    if "enum" in prop:
        return " \\| ".join(_code(v) for v in prop["enum"])
    for key in ("anyOf", "oneOf", "allOf"):
        if key in prop:
            return " or ".join(_schema_type(p) for p in prop[key])
    kind = prop.get("type", "any")
    if kind == "array":
        if "prefixItems" in prop:
            return "[" + ", ".join(_schema_type(p) for p in prop["prefixItems"]) + "]"
        return "list of " + _schema_type(prop.get("items", {}))
    if kind == "object" and "additionalProperties" in prop and isinstance(prop["additionalProperties"], dict):
        return "map of name to " + _schema_type(prop["additionalProperties"])
    return str(kind)


def _limits(prop: dict[str, Any]) -> str:
    marks = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<",
             "minLength": "length >=", "maxLength": "length <=", "minItems": "items >=", "maxItems": "items <="}
    out = [f"{sign} {prop[key]}" for key, sign in marks.items() if key in prop]
    for key in ("anyOf", "prefixItems"):
        for sub in prop.get(key, []):
            inner = _limits(sub)
            if inner and inner not in out:
                out.append(inner)
    if "items" in prop and isinstance(prop["items"], dict):
        inner = _limits(prop["items"])
        if inner:
            out.append(f"each {inner}")
    return ", ".join(out)


def _model_section(name: str, schema: dict[str, Any]) -> list[str]:
    lines = [f"## {name}", ""]
    if schema.get("description"):
        lines += [_prose(schema["description"]), ""]
    required = set(schema.get("required", []))
    lines += ["| field | type | required / default | unit | limits | description |", "|---|---|---|---|---|---|"]
    for field, prop in schema.get("properties", {}).items():
        default = "required" if field in required else (_code(prop["default"]) if "default" in prop else "optional")
        lines.append(
            f"| `{field}` | {_schema_type(prop)} | {default} | {_cell(field_unit(name, field))} | {_cell(_limits(prop))} | "
            f"{_cell(_prose(prop.get('description', '')))} |"
        )
    return lines + [""]


def job_page() -> str:
    from solver.schema.job import Job

    schema = Job.model_json_schema()
    defs = schema.pop("$defs", {})
    lines = [
        "# The job document",
        "",
        "Generated from the pydantic schema (`solver/schema/job.py`) that the command line and the",
        "HTTP API both validate with; the same schema is in `openapi.yaml`. Units come from the field",
        "names (`_mm` millimetres, `_m` metres, `_s` seconds, `_deg` degrees, `_px` pixels,",
        "`_m_s` metres per second); frames and conventions are in [Conventions](../conventions.md).",
        "Every object refuses fields it does not know; numbers are strict JSON numbers, finite.",
        "",
    ]
    lines += _model_section("Job", schema)
    for name in sorted(defs):
        lines += _model_section(name, defs[name])
    return "\n".join(lines)


def job_fields() -> dict[str, list[str]]:
    """Every model of the job schema with its field names (what the page must list)."""
    from solver.schema.job import Job

    schema = Job.model_json_schema()
    defs = schema.pop("$defs", {})
    out = {"Job": list(schema.get("properties", {}))}
    out.update({name: list(d.get("properties", {})) for name, d in defs.items()})
    return out


# ---------------------------------------------------------------- the command line ----------
def pba_parser() -> argparse.ArgumentParser:
    from service.cli import register
    from solver.cli import build_parser

    return build_parser(extra=(register,))


def walk_parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("pba",)):
    """Yield (command path, parser, help) for every parser below ``parser``, depth first."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield (*path, name), sub, helps.get(name, "")
                yield from walk_parsers(sub, (*path, name))


def _flags(action: argparse.Action) -> str:
    if action.option_strings:
        return ", ".join(f"`{s}`" for s in action.option_strings)
    return f"`{action.metavar or action.dest}`"


def cli_page() -> str:
    parser = pba_parser()
    lines = [
        "# The `pba` command line",
        "",
        "Generated from the argparse parsers of `pba` (`solver/cli.py` and the server's commands in",
        "`service/cli.py`). Every command answers `--help`; bad input exits with status 2 and a",
        "message naming the file, line and field.",
        "",
        "```text",
        parser.format_usage().strip(),
        "```",
        "",
    ]
    for path, sub, help_text in walk_parsers(parser):
        lines += [f"## {' '.join(path)}", ""]
        if help_text:
            lines += [_cell(help_text)[0:1].upper() + _cell(help_text)[1:] + ".", ""]
        if sub.description:
            lines += [sub.description, ""]
        lines += ["```text", sub.format_usage().strip(), "```", ""]
        actions = [a for a in sub._actions if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]
        if actions:
            lines += ["| argument | default | meaning |", "|---|---|---|"]
            for a in actions:
                default = "" if a.default in (None, argparse.SUPPRESS, False) or a.required else _code(a.default) if isinstance(a.default, (int, float, str, list)) else ""
                choices = f" (one of {', '.join(map(str, a.choices))})" if a.choices and not isinstance(a, argparse._SubParsersAction) else ""
                lines.append(f"| {_flags(a)} | {default} | {_cell((a.help or '') % {'default': a.default} if a.help and '%(' in a.help else a.help or '')}{_cell(choices)} |")
            lines.append("")
    return "\n".join(lines)


def cli_entries() -> dict[str, list[str]]:
    """Every command with its option strings and positional names (what the page must list)."""
    out = {}
    for path, sub, _ in walk_parsers(pba_parser()):
        names = []
        for a in sub._actions:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            names += list(a.option_strings) or [a.metavar or a.dest]
        out[" ".join(path)] = names
    return out


# ---------------------------------------------------------------- the HTTP API --------------
HTTP_METHODS = ("get", "post", "put", "patch", "delete")


def openapi_document() -> dict[str, Any]:
    return yaml.safe_load((ROOT / "openapi.yaml").read_text())


def _param_rows(op: dict[str, Any]) -> list[str]:
    rows = []
    for p in op.get("parameters", []):
        schema = p.get("schema", {})
        rows.append(f"| `{p['name']}` | {p['in']} | {_cell(_schema_type(schema))} | {'yes' if p.get('required') else ''} | {_cell(p.get('description', ''))} |")
    if not rows:
        return []
    return ["| parameter | in | type | required | description |", "|---|---|---|---|---|", *rows, ""]


def _body(op: dict[str, Any]) -> str:
    content = op.get("requestBody", {}).get("content", {})
    return ", ".join(
        f"`{media}`" + (f" ({_schema_type(c['schema'])})" if "schema" in c else "") for media, c in content.items()
    )


def http_page() -> str:
    doc = openapi_document()
    lines = [
        f"# HTTP API: {doc['info']['title']} {doc['info']['version']}",
        "",
        "Generated from `openapi.yaml` (which a test keeps equal to the running application's",
        "OpenAPI document; `make openapi` rewrites it). A running server also serves it at",
        "`/openapi.json`, browsable at `/docs`.",
        "",
        doc["info"].get("description", ""),
        "",
    ]
    for path, ops in doc["paths"].items():
        for method in HTTP_METHODS:
            if method not in ops:
                continue
            op = ops[method]
            lines += [f"## {method.upper()} {path}", ""]
            if op.get("description") or op.get("summary"):
                lines += [_prose(op.get("description") or op["summary"]), ""]
            body = _body(op)
            if body:
                lines += [f"Request body: {body}.", ""]
            lines += _param_rows(op)
            responses = op.get("responses", {})
            if responses:
                lines += ["| status | meaning |", "|---|---|"]
                lines += [f"| {code} | {_cell(r.get('description', ''))} |" for code, r in responses.items()]
                lines.append("")
    schemas = doc.get("components", {}).get("schemas", {})
    if schemas:
        lines += ["## Schemas", "", "The request and response bodies; the job document's models are described field by field",
                  "in [The job document](job.md).", ""]
        for name, schema in schemas.items():
            props = schema.get("properties", {})
            lines += [f"### {name}", "", _cell(_prose(schema.get("description", ""))), ""]
            if props:
                lines += ["| field | type | description |", "|---|---|---|"]
                lines += [f"| `{f}` | {_cell(_schema_type(p))} | {_cell(_prose(p.get('description', '')))} |" for f, p in props.items()]
                lines.append("")
    return "\n".join(lines)


def http_endpoints() -> list[str]:
    doc = openapi_document()
    return [f"{m.upper()} {path}" for path, ops in doc["paths"].items() for m in HTTP_METHODS if m in ops]


# ---------------------------------------------------------------- settings ------------------
def settings_page() -> str:
    from service.settings import Settings

    lines = [
        "# Server settings",
        "",
        "Generated from `service/settings.py`: environment variables with the prefix `PBA_`",
        "(pydantic-settings). `pba serve --host/--port/--workers/--data-dir` override the first ones.",
        "How they work together: [Run the shared lab server](../how-to/lab-server.md).",
        "",
        "| variable | type | default | unit | meaning |",
        "|---|---|---|---|---|",
    ]
    for name, field in Settings.model_fields.items():
        default = field.get_default(call_default_factory=True)
        shown = "" if default is None else _code(str(default) if isinstance(default, Path) else default)
        if hasattr(default, "get_secret_value"):
            shown = ""
        kind = getattr(field.annotation, "__name__", None) or str(field.annotation).replace("typing.", "")
        lines.append(f"| `PBA_{name.upper()}` | {_cell(kind)} | {shown} | {unit_of(name)} | {_cell(field.description or '')} |")
    from solver.engine.native import ENVIRONMENT

    lines += [
        "",
        "## Solver environment",
        "",
        "Read by every process that solves (`pba run` and the other solver commands, the server's workers),",
        "from `solver/engine/native/__init__.py`:",
        "",
        "| variable | default | meaning |",
        "|---|---|---|",
    ]
    for name, (default, meaning) in ENVIRONMENT.items():
        lines.append(f"| `{name}` | {_cell(default)} | {_cell(meaning)} |")
    return "\n".join(lines) + "\n"


def setting_names() -> list[str]:
    from service.settings import Settings
    from solver.engine.native import ENVIRONMENT

    return [f"PBA_{name.upper()}" for name in Settings.model_fields] + list(ENVIRONMENT)


# ---------------------------------------------------------------- platform models -----------
def platform_models_page() -> str:
    from solver.platforms import aliases, all_models, get_model

    lines = [
        "# Platform models",
        "",
        "Generated from the platform-model registry (`solver/platforms/`; `pba models` prints the",
        "same). Equations, derivations and where we differ from the papers: [Models](../models.md);",
        "which one to use: [Choose a platform model](../how-to/choose-model.md).",
        "",
        "| model | title | frame | time variable |",
        "|---|---|---|---|",
    ]
    described = [m.describe() for m in all_models()]
    lines += [f"| [{d['name']}](#{_anchor(d['name'])}) | {_cell(d['title'])} | {d['frame']} | {_cell(d['time_variable'])} |" for d in described]
    lines.append("")
    for d in described:
        lines += [f"## {d['name']}", "", f"{d['title']}. Frame {d['frame']}; time variable {d['time_variable']}.", ""]
        other = aliases(get_model(d["name"]))
        if other:
            lines += ["Also accepted as " + ", ".join(f"`{a}`" for a in other) + " (the same model).", ""]
        if d.get("equations"):
            lines += ["```text", d["equations"], "```", ""]
        lines += ["| parameter | unit |", "|---|---|"]
        lines += [f"| `{p['name']}` | {p['unit']} |" for p in d["parameters"]]
        lines.append("")
        if d.get("pass_parameters"):
            lines += ["Per pass (shared by its images, at the pass's reference epoch): "
                      + ", ".join(f"`{p['name']}` [{p['unit']}]" for p in d["pass_parameters"]) + ".", ""]
        if d.get("held"):
            lines += ["Held elements: " + ", ".join(f"`{h}`" for h in d["held"]) + ".", ""]
        if d.get("options"):
            lines += ["Options: " + "; ".join(f"`{k}`: {v}" for k, v in d["options"].items()) + ".", ""]
        if d.get("reference"):
            lines += [f"Source: {d['reference']}", ""]
    return "\n".join(lines)


def platform_model_names() -> list[str]:
    from solver.platforms import all_models

    return [m.describe()["name"] for m in all_models()]


# ---------------------------------------------------------------- report keys ---------------
REPORT_FIXTURES = ROOT / "tests" / "fixtures" / "reports"


def report_key_paths() -> dict[str, tuple[str, Any]]:
    """Every key path of the pinned example reports (``a/b[]/c``) -> (JSON type, an example)."""
    import gzip

    found: dict[str, tuple[str, Any]] = {}

    def walk(node: Any, path: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                here = f"{path}/{key}" if path else key
                if here not in found:
                    found[here] = (type(value).__name__, value if isinstance(value, (int, float, str, bool)) or value is None else None)
                walk(value, here)
        elif isinstance(node, list):
            for item in node:
                walk(item, path + "[]")

    for fixture in sorted(REPORT_FIXTURES.glob("*.report.json.gz")):
        with gzip.open(fixture, "rt") as f:
            walk(json.load(f), "")
    return dict(sorted(found.items()))


def report_keys_page() -> str:
    names = {"dict": "object", "list": "list", "str": "string", "float": "number", "int": "integer", "bool": "boolean", "NoneType": "null"}
    lines = [
        "# Report keys",
        "",
        "Generated from the reports of the example jobs (`examples/*.json`, pinned in",
        "`tests/fixtures/reports/`): every key path a report of these jobs holds, with its JSON type and",
        "an example value. What each key means, and the keys of sections these examples do not",
        "produce (self-calibration, lines, data snooping, comparisons): [The report](../report-contract.md),",
        "which documents every key listed here (a test checks it).",
        "",
        "| key path | type | example |",
        "|---|---|---|",
    ]
    for path, (kind, example) in report_key_paths().items():
        shown = "" if example is None else _code(round(example, 6) if isinstance(example, float) else example)
        lines.append(f"| `{path}` | {names.get(kind, kind)} | {_cell(shown)[:80]} |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- all -----------------------
def pages() -> dict[str, str]:
    """Every generated page: path under docs/ -> Markdown."""
    return {
        "reference/job.md": job_page(),
        "reference/cli.md": cli_page(),
        "reference/http-api.md": http_page(),
        "reference/settings.md": settings_page(),
        "reference/platform-models.md": platform_models_page(),
        "reference/report-keys.md": report_keys_page(),
    }


def write(outdir: Path) -> list[Path]:
    written = []
    for rel, text in pages().items():
        path = outdir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outdir", type=Path, help="folder to write reference/*.md into")
    args = parser.parse_args(argv)
    for path in write(args.outdir):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["pages", "write", "job_fields", "cli_entries", "http_endpoints", "setting_names", "platform_model_names", "unit_of", "field_unit"]
