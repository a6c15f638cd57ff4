"""solver/simulate is the independent truth: it imports nothing of the solver core but the
geometry (solver.geometry: CRS plumbing and the chip rule), so recovery tests on its scenes cannot share a physics error with the
solver (a sign, a frame, a pixel convention written once and used by both)."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

SIMULATE = Path(__file__).resolve().parents[3] / "solver" / "simulate"
# the geometry shared by design (issue 14): CRS plumbing and the chip-of-a-column rule; (issue 17)
# the RPC00B polynomial, its least-squares fit and the bias equations of RPC images (the
# simulated RPC images' truth is checked through GDAL, tests/solver/simulate/test_simulate_rpc.py)
# the raster gate writes the simulated rasters (file plumbing, no physics: every raster goes through it)
ALLOWED = {"solver.geometry", "solver.geometry.geodesy", "solver.geometry.sensor", "solver.geometry.rpc", "solver.raster_gate"}


def test_simulate_sources_import_only_geometry_from_the_solver() -> None:
    found = {}
    for path in sorted(SIMULATE.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names if node.module == "solver"]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                if name.startswith("solver") and not name.startswith("solver.simulate") and name != "solver":
                    found.setdefault(name, []).append(path.name)
    assert set(found) <= ALLOWED, found


def test_importing_every_simulate_module_loads_no_other_solver_module() -> None:
    """Transitive imports too (geodesy's own imports included), in a fresh interpreter."""
    modules = [f"solver.simulate.{p.stem}" for p in SIMULATE.glob("*.py") if p.stem != "__init__"]
    code = (
        "import importlib, json, sys\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('solver'))))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=SIMULATE.parents[1])
    loaded = set(json.loads(out.stdout.strip().splitlines()[-1]))
    core = {m for m in loaded if m != "solver" and not m.startswith("solver.simulate")}
    assert core <= ALLOWED, core
