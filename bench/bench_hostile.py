"""Benchmark of hostile uploads: the API process's time and peak memory per hostile request.

Starts its own ``pba serve`` (local mode, ``--workers`` local workers), sends each hostile
request of the list below once and reports its answer (status, problem code), its wall time and
the API process's RSS before it, its peak RSS during it (Linux: ``VmHWM`` of /proc/PID/status,
reset before each request by writing 5 to /proc/PID/clear_refs) and its RSS afterwards (the
API process starts near 125 MB: it loads neither numba nor scipy; RPC fits and transforms run in
the GIS process). The goal: every one refused or answered within 2 s and 300 MB of RSS.

Usage: ``python bench/bench_hostile.py [--workers 1]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_service import start_server, stop_server  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
GOAL_S, GOAL_MB = 2.0, 300.0  # every hostile request refused or answered within these
BOUNDARY = b"pba-bench-boundary"
HALF_RPC_XML = (
    b"<?xml version='1.0'?><Dimap_Document><Rational_Function_Model><Global_RFM><RFM_Validity>"
    b"<LONG_SCALE>1</LONG_SCALE><LAT_SCALE>1</LAT_SCALE></RFM_Validity></Global_RFM>"
    b"</Rational_Function_Model></Dimap_Document>"
)


def multipart(spec: str, files: list[tuple[bytes, bytes]]) -> bytes:
    """A multipart body written by hand (file names as raw bytes)."""
    def part(disposition: bytes, data: bytes) -> bytes:
        return b"--" + BOUNDARY + b"\r\nContent-Disposition: form-data; " + disposition + b"\r\n\r\n" + data + b"\r\n"

    out = [part(b'name="spec"', spec.encode())]
    out += [part(b'name="files"; filename="' + n + b'"\r\nContent-Type: application/octet-stream', d) for n, d in files]
    return b"".join(out) + b"--" + BOUNDARY + b"--\r\n"


def image(measurements: list[str], **more: Any) -> dict[str, Any]:
    return {"id": "A", "camera": "prism-nadir", "measurements": measurements, **more}


def cases() -> list[tuple[str, str, list[tuple[bytes, bytes]]]]:
    """(label, spec, files) of every hostile upload."""
    tie_rows = b"point,line,column\n" + b"".join(b"t%07d,%d.5,%d.25\n" % (i, i % 9000, i % 7000) for i in range(1_000_000))
    survey = b"id,x,y,z,role\n" + b"".join(b"p%07d,-51.%06d,-22.%06d,400.0,gcp\n" % (i, i, i) for i in range(1_000_000))
    small = (ROOT / "examples" / "prism-triplet-sources" / "prism-nadir-ties.csv").read_bytes()
    rpc = {"images": [{"id": "A", "rpc": "RPC_SPOT6.XML", "measurements": ["m.csv"]}]}
    return [
        ("XML GDAL half-reads as an RPC", json.dumps(rpc), [(b"RPC_SPOT6.XML", HALF_RPC_XML), (b"m.csv", b"point,line,column\n")]),
        ("NUL in a file name", json.dumps(rpc), [(b"a\x00_RPC.TXT", b"x"), (b"m.csv", b"x")]),
        ("300-character file name", json.dumps(rpc), [(b"x" * 292 + b"_RPC.TXT", b"x"), (b"m.csv", b"x")]),
        ("spec nested 100,000 deep", '{"images": [{"id": "A"}], "options": ' + "[" * 100_000 + "]" * 100_000 + "}", [(b"m.csv", b"x")]),
        (
            "camera file nested 100,000 deep",
            json.dumps({"images": [image(["m.csv"], camera="c")], "camera_files": ["c.json"]}),
            [(b"c.json", b"[" * 100_000 + b"]" * 100_000), (b"m.csv", b"point,line,column\np,1,2\n")],
        ),
        ("CSV field of 200,000 bytes", json.dumps({"images": [image(["m.csv"])]}), [(b"m.csv", b'point,line,column\n"' + b"x" * 200_000 + b'",1,2\n')]),
        ("survey header of 100,000 columns", json.dumps({"images": [image(["m.csv"])], "gcps": ["s.csv"]}), [(b"s.csv", ",".join(f"c{i}" for i in range(100_000)).encode() + b"\n"), (b"m.csv", small)]),
        (
            f"one {len(small) / 1000:.1f} kB file named 200 times in 64 images",
            json.dumps({"images": [{"id": f"I{k}", "camera": "prism-nadir", "measurements": [f"m{j}.csv" for j in range(200)]} for k in range(64)]}),
            [(f"m{j}.csv".encode(), small) for j in range(200)],
        ),
        ("tie CSV at the row limit (19,990 rows): composed", json.dumps({"images": [image(["m.csv"])]}), [(b"m.csv", b"\n".join(tie_rows.split(b"\n")[:19_991]) + b"\n")]),
        (f"tie CSV of a million rows ({len(tie_rows) / 1e6:.0f} MB)", json.dumps({"images": [image(["m.csv"])]}), [(b"m.csv", tie_rows)]),
        (f"survey of a million rows ({len(survey) / 1e6:.0f} MB)", json.dumps({"images": [image(["m.csv"])], "points": ["s.csv"]}), [(b"s.csv", survey), (b"m.csv", small)]),
    ]


def rss_kb(pid: int) -> tuple[int, int]:
    """(peak RSS since the last reset, current RSS) of ``pid``, kB."""
    fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    return int(fields["VmHWM"].split()[0]), int(fields["VmRSS"].split()[0])


def reset_peak(pid: int) -> None:
    Path(f"/proc/{pid}/clear_refs").write_text("5")


def measure(pid: int, send: Any) -> dict[str, Any]:
    _, before = rss_kb(pid)
    reset_peak(pid)
    t0 = time.perf_counter()
    r = send()
    dt = time.perf_counter() - t0
    peak, now = rss_kb(pid)
    code = ""
    if r.headers.get("content-type", "").startswith("application/problem+json"):
        doc = r.json()
        code = (doc.get("errors") or [{}])[0].get("code") or doc.get("type", "").rsplit(":", 1)[-1]
    return {"status": r.status_code, "code": code, "seconds": round(dt, 3), "rss_before_mb": round(before / 1024, 1), "peak_rss_mb": round(peak / 1024, 1), "rss_after_mb": round(now / 1024, 1), "answer_mb": round(len(r.content) / 1e6, 3)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--settle-s", type=float, default=15.0, help="wait after start-up: the workers and the GIS process load their libraries on the same cores")
    args = ap.parse_args()
    data_dir = Path(tempfile.mkdtemp(prefix="pba-bench-hostile-"))
    proc, url = start_server(data_dir, args.workers)
    time.sleep(args.settle_s)
    rows = []
    try:
        with httpx.Client(base_url=url, timeout=600) as c:
            content_type = {"content-type": "multipart/form-data; boundary=" + BOUNDARY.decode()}
            for label, spec, files in cases():
                body = multipart(spec, files)
                row = measure(proc.pid, lambda: c.post("/jobs/compose", content=body, headers=content_type))
                rows.append({"request": label, **row})
                print(json.dumps(rows[-1]), flush=True)
            if args.workers:
                job = json.loads((ROOT / "examples" / "prism-nadir.json").read_text())
                r = c.post("/processes/bundle-adjustment/execution", json={"inputs": {"job": job}})
                job_url = r.headers["location"].split(url, 1)[-1]
                while c.get(job_url).json()["status"] in ("accepted", "running"):
                    time.sleep(1)
                row = measure(proc.pid, lambda: c.get(f"{job_url}/results/rpc/prism-nadir", params={"chip": "99"}))
                rows.append({"request": "RPC download of chip 99", **row})
                print(json.dumps(rows[-1]), flush=True)

                def three_at_once() -> httpx.Response:
                    """Three downloads of one chip's RPC at once (one fit, the others wait for it)."""
                    with ThreadPoolExecutor(3) as pool:
                        answers = list(pool.map(lambda _: c.get(f"{job_url}/results/rpc/prism-nadir", params={"chip": "2"}), range(3)))
                    return max(answers, key=lambda a: a.status_code)

                row = measure(proc.pid, three_at_once)
                rows.append({"request": "RPC download of chip 2, three at once", **row})
                print(json.dumps(rows[-1]), flush=True)
            row = measure(proc.pid, lambda: c.get("/cameras/shared/prism-nadir/versions", params={"limit": 1000}))
            rows.append({"request": "camera versions, limit=1000", **row})
            print(json.dumps(rows[-1]), flush=True)
    finally:
        stop_server(proc, data_dir)
    width = max(len(r["request"]) for r in rows)
    for r in rows:
        verdict = "ok" if r["seconds"] <= GOAL_S and r["peak_rss_mb"] <= GOAL_MB else "OVER"
        print(f"{r['request']:<{width}}  {r['status']} {r['code']:<22} {r['seconds']:7.3f} s  before {r['rss_before_mb']:7.1f} MB  peak {r['peak_rss_mb']:7.1f} MB  after {r['rss_after_mb']:7.1f} MB  {verdict}")
    over = [r["request"] for r in rows if r["seconds"] > GOAL_S or r["peak_rss_mb"] > GOAL_MB]
    print(f"goal (within {GOAL_S:g} s and {GOAL_MB:g} MB of API-process RSS): " + ("met by every request" if not over else f"NOT met by {over}"))
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
