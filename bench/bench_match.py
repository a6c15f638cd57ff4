"""Speed and peak memory of ``pba match`` on large synthetic rasters with RPCs.

Scenes (generated on the fly into a temporary directory, never held whole in memory):

- ``pair``: two 10,000 x 10,000 16-bit images;
- ``crops``: three 1,024 x 1,024 crops (the size of the real triplet the speed target names);
- ``prism``: a PRISM-size triplet, three 16,000 lines x 14,500 columns.

Each image sees one flat textured ground (a random lattice every 3 pixels, bicubic, plus
per-image gain, offset and noise) through a linear RPC whose line depends on the height
(+-0.1 per normalised height unit: the views' parallax), the ground at 37.3 m above the RPC's
height offset, so neighbouring views are shifted by a non-integer number of lines, and the
images are offset along track by 5% of their length (partial overlap). The matching is run
as a separate ``pba match`` process (its own peak RSS and CPU time from ``getrusage``), with the
default settings; the load (``os.getloadavg``) is printed beside every time: on a shared machine
the time is only indicative. The package's bytecode is compiled first (``compileall``), as an
installation has it (pip compiles it at install): with ``PYTHONDONTWRITEBYTECODE`` set, as on
some development machines, every run would otherwise compile the solver's modules again
(about 0.2 s).

Usage: ``python bench/bench_match.py [--scene crops|pair|prism|all] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import compileall
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LATTICE_PX = 3.0
TERRAIN_ABOVE_M = 37.3
HEIGHT_OFF_M, HEIGHT_SCALE_M = 500.0, 500.0
PARALLAX = 0.1  # normalised line per normalised height, +- between views
BLOCK = 512


def _rpc(lines: int, columns: int, line_offset: float, parallax: float):
    """A linear RPC: line = line_off + line_scale (-Y + parallax Z), sample = samp_off + samp_scale X."""
    from solver.geometry.rpc import RPC

    num_l = np.zeros(20)
    num_l[2], num_l[3] = -1.0, parallax
    num_s = np.zeros(20)
    num_s[1] = 1.0
    den = np.zeros(20)
    den[0] = 1.0
    deg = 2e-5  # ~2 m per pixel
    return RPC(
        line_off=(lines - 1) / 2.0 - line_offset, samp_off=(columns - 1) / 2.0, lat_off=-22.0, long_off=-51.0,
        height_off=HEIGHT_OFF_M, line_scale=lines / 2.0, samp_scale=columns / 2.0, lat_scale=deg * lines / 2.0,
        long_scale=deg * columns / 2.0, height_scale=HEIGHT_SCALE_M, line_num=num_l, line_den=den.copy(), samp_num=num_s, samp_den=den.copy(),
    )


def write_image(path: Path, lattice: np.ndarray, lines: int, columns: int, ground_row0: float, seed: int) -> None:
    """One 16-bit tiled GeoTIFF: image row l sees the ground row ``l + ground_row0``."""
    import cv2
    import rasterio
    from rasterio.windows import Window

    rng = np.random.default_rng(seed)
    gain, offset = rng.uniform(0.8, 1.2), rng.uniform(-10, 10)
    with rasterio.open(path, "w", driver="GTiff", width=columns, height=lines, count=1, dtype="uint16", tiled=True, blockxsize=512, blockysize=512) as dst:
        cols = np.arange(columns, dtype=np.float32) / LATTICE_PX
        for r0 in range(0, lines, BLOCK):
            n = min(BLOCK, lines - r0)
            rows = (np.arange(r0, r0 + n, dtype=np.float32) + ground_row0) / LATTICE_PX
            mx, my = np.meshgrid(cols, rows)
            v = cv2.remap(lattice, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
            v = gain * v + offset + rng.normal(0, 2.0, v.shape).astype(np.float32)
            dst.write(np.clip((v + 100) * 64, 0, 65535).astype(np.uint16), 1, window=Window(0, r0, columns, n))


def make_scene(d: Path, n_images: int, lines: int, columns: int) -> list[Path]:
    from solver.gis.rpc_io import write_sidecar

    rng = np.random.default_rng(7)
    shift = 0.05 * lines
    total = lines + int(shift * (n_images - 1)) + 200
    lattice = rng.normal(0, 25, (int(total / LATTICE_PX) + 8, int(columns / LATTICE_PX) + 8)).astype(np.float32)
    z = TERRAIN_ABOVE_M / HEIGHT_SCALE_M
    paths = []
    for i in range(n_images):
        p = PARALLAX * (i - (n_images - 1) / 2.0)
        line_offset = i * shift
        rpc = _rpc(lines, columns, line_offset, p)
        # ground row of image line l: the RPC's line at the terrain's height, inverted
        ground_row0 = line_offset - p * z * (lines / 2.0) + 100
        path = d / f"view{i}.tif"
        write_image(path, lattice, lines, columns, ground_row0, seed=i)
        write_sidecar(rpc, d / f"view{i}_RPC.TXT")
        paths.append(path)
    del lattice
    return paths


def run_match(paths: list[Path], out: Path) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    usage0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "solver.cli", "match", *map(str, paths), "-o", str(out), "--summary", str(out.with_suffix(".json")), "-q",
           "--heights", f"{HEIGHT_OFF_M - 200},{HEIGHT_OFF_M + 200}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    seconds = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak_mb = usage.ru_maxrss / 1024.0
    cpu = usage.ru_utime + usage.ru_stime - usage0.ru_utime - usage0.ru_stime
    return {"ok": proc.returncode == 0, "seconds": seconds, "cpu_s": cpu, "peak_rss_mb": max(peak_mb, before / 1024.0), "load": (load0, os.getloadavg()[0]),
            "stdout": proc.stdout.strip().splitlines()[:1], "stderr": proc.stderr.strip()[-500:]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=("crops", "pair", "prism", "all"), default="all")
    ap.add_argument("--keep", type=Path, help="write the rasters here and keep them (a scene already kept there is used again)")
    args = ap.parse_args()
    scenes = {"crops": (3, 1024, 1024), "pair": (2, 10_000, 10_000), "prism": (3, 16_000, 14_500)}
    names = list(scenes) if args.scene == "all" else [args.scene]
    compileall.compile_dir(str(ROOT / "solver"), quiet=1)
    with tempfile.TemporaryDirectory(prefix="pba-bench-match-") as tmp:
        base = args.keep or Path(tmp)
        for name in names:
            d = base / name
            d.mkdir(parents=True, exist_ok=True)
            t0 = time.perf_counter()
            kept = [d / f"view{i}.tif" for i in range(scenes[name][0])]
            if args.keep and all(p.exists() and p.with_name(p.stem + "_RPC.TXT").exists() for p in kept):
                paths = kept
                print(f"{name}: the scene kept in {d} used again")
            else:
                paths = make_scene(d, *scenes[name])
                print(f"{name}: {scenes[name][0]} images {scenes[name][1]} x {scenes[name][2]} written in {time.perf_counter() - t0:.0f} s")
            r = run_match(paths, d / "ties.csv")
            print(f"{name}: pba match {'ok' if r['ok'] else 'FAILED'} in {r['seconds']:.1f} s ({r['cpu_s']:.1f} s CPU), peak RSS {r['peak_rss_mb']:.0f} MB "
                  f"(load average {r['load'][0]:.1f} before, {r['load'][1]:.1f} after)")
            print("  " + " ".join(r["stdout"]))
            if not r["ok"]:
                print(r["stderr"])


if __name__ == "__main__":
    main()
