"""Every raster open in solver/ and service/ goes through the raster gate (solver/raster_gate.py).

The sources are parsed (AST) for the ways Python code reaches GDAL's open: ``rasterio.open``
(read or write), rasterio's ``MemoryFile``/``ZipMemoryFile``/``DatasetReader``/``DatasetWriter``
and ``rasterio.shutil``, GDAL's own bindings (``osgeo``), and the GDAL options that make GDAL
open a file by itself (``RPC_DEM``, ``OVERVIEW_FILE``...) unless given the gate's private name
of a raster the gate opened (``.gdal_name``). Any of them outside the gate fails, with the list
of call sites. The scanner's own test shows it finds each kind.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GATE = ROOT / "solver" / "raster_gate.py"
PACKAGES = ("solver", "service")
OPENERS = {"open", "MemoryFile", "ZipMemoryFile", "DatasetReader", "DatasetWriter", "BufferedDatasetWriter", "get_writer_for_path", "get_writer_for_driver"}
PATH_OPTIONS = {"RPC_DEM", "OVERVIEW_FILE", "SRC_METHOD_DEM", "DEM", "CUTLINE"}


def _dotted(node: ast.AST) -> str:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
    return ".".join(reversed(parts))


def call_sites(source: str, name: str) -> list[str]:
    """``file:line: what`` for every way ``source`` reaches GDAL's open outside the gate."""
    tree = ast.parse(source)
    found: list[str] = []
    rasterio_names = {"rasterio"}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "osgeo" or alias.name.startswith("osgeo."):
                    found.append(f"{name}:{node.lineno}: import {alias.name} (GDAL's own bindings)")
                if alias.name == "rasterio":
                    rasterio_names.add(alias.asname or "rasterio")
        elif isinstance(node, ast.ImportFrom) and node.module:
            mod = node.module
            if mod == "osgeo" or mod.startswith("osgeo."):
                found.append(f"{name}:{node.lineno}: from {mod} import ... (GDAL's own bindings)")
            if mod.startswith("rasterio"):
                for alias in node.names:
                    if alias.name in OPENERS or mod.startswith("rasterio.shutil"):
                        found.append(f"{name}:{node.lineno}: from {mod} import {alias.name}")
        elif isinstance(node, ast.Call):
            dotted = _dotted(node.func)
            head, _, attr = dotted.rpartition(".")
            if attr in OPENERS and head.split(".")[0] in rasterio_names:
                found.append(f"{name}:{node.lineno}: {dotted}(...)")
            if head.split(".")[0] in rasterio_names and ".shutil" in f".{head}":
                found.append(f"{name}:{node.lineno}: {dotted}(...)")
            for kw in node.keywords:
                if kw.arg in PATH_OPTIONS and ".gdal_name" not in ast.unparse(kw.value):
                    found.append(f"{name}:{node.lineno}: {kw.arg}= (GDAL opens that file itself)")
        elif isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value in PATH_OPTIONS and ".gdal_name" not in ast.unparse(value):
                    found.append(f"{name}:{node.lineno}: {key.value!r}: (GDAL opens that file itself)")
    return found


def test_every_raster_open_goes_through_the_gate() -> None:
    found = []
    scanned = 0
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path == GATE:
                continue
            scanned += 1
            found += call_sites(path.read_text(), str(path.relative_to(ROOT)))
    assert scanned > 100
    assert found == [], "raster opens that bypass solver/raster_gate.py:\n" + "\n".join(found)


def test_the_gate_itself_is_where_the_opens_are() -> None:
    assert len(call_sites(GATE.read_text(), "gate")) >= 2  # its DatasetReader and rasterio.open(.., "w")


def test_the_scanner_finds_each_kind() -> None:
    samples = {
        "import rasterio\nrasterio.open(p)\n": 1,
        "import rasterio as rio\nwith rio.open(p, 'w', driver='GTiff') as d: pass\n": 1,
        "from rasterio.io import MemoryFile\nMemoryFile(b)\n": 1,
        "from rasterio import open as o\n": 1,
        "import rasterio.io\nrasterio.io.DatasetReader(p)\n": 1,
        "import rasterio.shutil\nrasterio.shutil.copy(a, b)\n": 1,
        "from osgeo import gdal\n": 1,
        "import osgeo.gdal\n": 1,
        "reproject(a, b, RPC_DEM=str(dem))\n": 1,
        "opts = {'RPC_DEM': path}\n": 1,
        "reproject(a, b, RPC_DEM=gated.gdal_name)\n": 0,
        "from solver.raster_gate import open_raster\nopen_raster(p)\n": 0,
        "import rasterio\nrasterio.band(ds, 1)\nrasterio.Env()\n": 0,
    }
    for source, n in samples.items():
        assert len(call_sites(source, "s")) == n, source
