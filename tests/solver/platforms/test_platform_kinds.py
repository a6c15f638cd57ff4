"""The platform kind is asked in one place: the kind object of the registry (solver/platforms/kinds.py).

- No module of solver/ or service/ outside solver/platforms/ and solver/kernels/ branches on the
  model kind: no ``KIND_*`` code, no ``.orbital`` / ``.propagated`` / ``.is_rpc`` (the flags
  the kind object replaced), no comparison or ``isinstance`` of a ``.kind`` with anything but an
  observation group's string kind. The scan is checked on the forms it replaced.
- A new kind is its module, its kernel and the registry lines: tests/solver/platforms/fake_platform_kind.py adds
  one (nothing in solver/ changes) and a job with it is validated, solved and reported, with the
  same adjusted trajectory as the line-time model P1 on the same scene.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from fake_platform_kind import install
from utils.scenes import single_image_job, truth_parameters

import solver.platforms.kinds as kinds_module
import solver.platforms.registry as registry
from solver.api import run, validate

ROOT = Path(__file__).resolve().parents[3]
ALLOWED = (ROOT / "solver" / "platforms", ROOT / "solver" / "kernels")
FLAGS = {"orbital", "propagated", "is_rpc"}  # the kind tests the kind object replaced
SAME_TRAJECTORY_SIGMAS = 1e-3  # two parametrisations of one model solve to one minimum: far below its sigma


def _kind_operand(node: ast.AST) -> bool:
    """``x.kind``, ``x.kind.kernel`` or ``x.kind.name``: the kind itself, not a capability."""
    return _kind_identity(node) or (isinstance(node, ast.Attribute) and node.attr == "kind")


def _kind_identity(node: ast.AST) -> bool:
    """``x.kind.kernel`` or ``x.kind.name``: which kind it is, whatever it is compared with."""
    return isinstance(node, ast.Attribute) and node.attr in ("kernel", "name") and _kind_operand(node.value)


def _strings(node: ast.AST) -> bool:
    """A string constant or a tuple, list or set of them (an observation group's kinds)."""
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return all(_strings(e) for e in node.elts)
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def kind_branches(source: str) -> list[str]:
    """Where ``source`` branches on the platform kind (line: what)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr in FLAGS:
            out.append(f"{node.lineno}: .{node.attr}")
        elif isinstance(node, ast.Name) and node.id.startswith("KIND_"):
            out.append(f"{node.lineno}: {node.id}")
        elif isinstance(node, ast.alias) and node.name.startswith("KIND_"):
            out.append(f"import {node.name}")
        elif isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            strings = all(_strings(s) for s in sides if not _kind_operand(s))
            if any(_kind_identity(s) for s in sides) or (any(_kind_operand(s) for s in sides) and not strings):
                out.append(f"{node.lineno}: comparison of a kind")
        elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance" and node.args and _kind_operand(node.args[0]):
            out.append(f"{node.lineno}: isinstance of a kind")
    return out


def test_the_scan_finds_the_forms_it_forbids():
    forbidden = [
        "if model.orbital: pass",
        "x = img.model.propagated",
        "if m.is_rpc: pass",
        "from solver.kernels import KIND_PASS",
        "y = img.kind in (KIND_ORBIT_ATTITUDE, KIND_PASS)",
        "z = model.kind == 2",
        "z = model.kind.kernel != 4",
        "z = model.kind.name == 'pass'",
        "z = isinstance(model.kind, OrbitKind)",
    ]
    for src in forbidden:
        assert kind_branches(src), src
    allowed = ["if g.kind == 'line_point': pass", "ok = g.kind not in ('image_point', 'control_point')", "if model.kind.shares_pass_orbit: pass", "project(img.kind, coef)"]
    for src in allowed:
        assert not kind_branches(src), src


def test_no_module_outside_platforms_and_kernels_branches_on_the_kind():
    found = {}
    for path in sorted([*(ROOT / "solver").rglob("*.py"), *(ROOT / "service").rglob("*.py")]):
        if any(path.is_relative_to(a) for a in ALLOWED):
            continue
        hits = kind_branches(path.read_text(encoding="utf-8"))
        if hits:
            found[str(path.relative_to(ROOT))] = hits
    assert not found, found


@pytest.fixture
def fake_kind(monkeypatch):
    """The fake kind registered for one test; the registries are restored after it."""
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    monkeypatch.setattr(kinds_module, "_KINDS", dict(kinds_module._KINDS))
    return install()


def test_a_new_kind_by_its_module_is_validated_solved_and_reported(fake_kind):
    assert fake_kind.kind in kinds_module.all_kinds()
    job, truth = single_image_job("FAKE-S2", seed=6)
    checked = validate(job)
    assert checked["valid"], checked["problems"]
    assert checked["images"][0]["model"] == "FAKE-S2" and checked["images"][0]["n_parameters"] == 13
    rep = run(job)
    a = rep["adjustment"]
    assert a["converged"], a["message"]
    assert 0.5 < a["sigma0_aposteriori"] < 1.6  # 0.5 px noise at sigma 0.5 px: sigma0 near 1
    im = rep["images"][0]
    units = {p["name"]: p["unit"] for p in im["parameters"]}
    assert units["X1"] == "m/s" and units["X2"] == "m/s^2" and units["kappa1"] == "deg/s"  # the kind's names
    tp = truth_parameters("FAKE-S2", np.array(truth["coef"]), job["images"][0]["model"]["options"])
    z = np.array([(p["value"] - tp[p["name"]]) / p["sigma"] for p in im["parameters"] if p["estimated"]])
    assert np.all(np.abs(z) <= 3.0), z  # its own truth within 3 of its sigmas

    # the same scene with P1 (same orders, time = line number): the same adjusted trajectory
    job_p1 = {**job, "images": [{**job["images"][0], "model": {"name": "P1", "options": {}}}]}
    p1 = {p["name"]: p for p in run(job_p1)["images"][0]["parameters"]}
    lt = next(c for c in job["cameras"] if c["id"] == job["images"][0]["camera"])["line_time_s"]
    for p in im["parameters"]:
        e, k = p["name"][:-1], int(p["name"][-1])
        name = f"{e}{k}" if e in "XYZ" else (e if k == 0 else f"{e}{k}")
        q = p1[name]  # P1 per line^k, FAKE-S2 per s^k
        assert abs(p["value"] * lt**k - q["value"]) <= SAME_TRAJECTORY_SIGMAS * q["sigma"], (name, p["value"] * lt**k, q["value"])
