"""A job's measurements back in the formats they come in: the inverse of the composer.

:func:`write_sources` writes, for a job document, the files ``pba job`` reads back into the
same content: the survey (``survey.csv``, control and check points with a role column), the
cameras (``cameras.json``), and per image its measurements in the chosen format (``csv``,
``qgis`` ``.points`` with the tie points, which a ``.points`` file has no room for, in a
``-ties.csv`` beside it, or ``asp`` ``.gcp`` likewise), its header state, ephemeris,
attitude and attitude-base tables, and an RPC image's RPC as ``ID_RPC.TXT``. It returns the ``pba job`` arguments that rebuild the job.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from solver.geometry.rpc import RPC
from solver.gis.rpc_io import rpc_txt
from solver.importers.asp_gcp import write_asp_gcp
from solver.importers.attitude_csv import write_attitude
from solver.importers.ephemeris_csv import write_ephemeris, write_state
from solver.importers.measurements_csv import write_measurements
from solver.importers.points_csv import write_points
from solver.importers.qgis_points import write_qgis_points

FORMATS = ("csv", "qgis", "asp")


def write_sources(
    job: dict[str, Any], out_dir: Path, formats: dict[str, str] | None = None, time_scale: str = "GPS"
) -> list[str]:
    """Write the job's source files into ``out_dir``; the ``pba job`` arguments (file names
    relative to ``out_dir``) that compose the same job again. ``formats``: image id ->
    ``csv`` | ``qgis`` | ``asp`` (default csv)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    crs = job.get("crs", "EPSG:4326")
    points = job.get("points", [])
    surveyed = [p for p in points if p["role"] != "tie"]
    ties = {p["id"] for p in points if p["role"] == "tie"}
    args = ["--name", job.get("name", "job"), "--crs", crs]
    (out_dir / "survey.csv").write_text(write_points(surveyed, crs))
    args += ["--points", "survey.csv"]
    if job.get("cameras"):
        (out_dir / "cameras.json").write_text(json.dumps(job["cameras"], indent=1) + "\n")
        args += ["--camera-file", "cameras.json"]
    models = {im["model"]["name"] for im in job["images"] if not im.get("rpc")}
    if models:
        args += ["--model", ",".join(sorted(models))]
    for im in job["images"]:
        iid = im["id"]
        if im.get("rpc"):  # an RPC image: its RPC as GDAL's NAME_RPC.TXT (RPC00B's pixel convention)
            (out_dir / f"{iid}_RPC.TXT").write_text(rpc_txt(RPC.from_job(im["rpc"])))
            args += ["--rpc", f"{iid}={iid}_RPC.TXT", "--rpc-model", f"{iid}={im['model']['name']}"]
        obs = [o for o in job.get("observations", []) if o["image"] == iid]
        fmt = (formats or {}).get(iid, "csv")
        if fmt == "csv":
            (out_dir / f"{iid}.csv").write_text(write_measurements(obs, with_image=False))
            args += ["--image", f"{iid}={iid}.csv"]
        else:
            own = [o for o in obs if o["point"] not in ties]
            if fmt == "qgis":
                text, _ = write_qgis_points(own, points, crs)
                name = f"{iid}.points"
            else:
                text, _ = write_asp_gcp(surveyed, own, crs)
                name = f"{iid}.gcp"
            (out_dir / name).write_text(text)
            args += ["--image", f"{iid}={name}"]
            tie_obs = [o for o in obs if o["point"] in ties]
            if tie_obs:
                (out_dir / f"{iid}-ties.csv").write_text(write_measurements(tie_obs, with_image=False))
                args += ["--image", f"{iid}={iid}-ties.csv"]
        if im.get("camera") and im["camera"] != iid:
            args += ["--camera", f"{iid}={im['camera']}"]
        if im.get("approx_state") and im.get("first_line_time_s") is not None:
            state = {k: im["approx_state"][k] for k in ("position_ecef_m", "velocity_ecef_m_s")}
            (out_dir / f"{iid}.state.csv").write_text(write_state(im["first_line_time_s"], state, time_scale))
            args += ["--state", f"{iid}={iid}.state.csv"]
        elif im.get("first_line_time_s") is not None:  # no header state to carry it (vendor metadata: an ephemeris)
            args += ["--first-line-time", f"{iid}={im['first_line_time_s']!r}"]
        if im.get("ephemeris"):
            (out_dir / f"{iid}.ephemeris.csv").write_text(write_ephemeris(im["ephemeris"], time_scale))
            args += ["--ephemeris", f"{iid}={iid}.ephemeris.csv"]
        if im.get("attitude"):
            (out_dir / f"{iid}.attitude.csv").write_text(write_attitude(im["attitude"], time_scale))
            args += ["--attitude", f"{iid}={iid}.attitude.csv"]
        if im.get("attitude_base"):
            (out_dir / f"{iid}.attitude-base.csv").write_text(write_attitude(im["attitude_base"], time_scale))
            args += ["--attitude-base", f"{iid}={iid}.attitude-base.csv"]
    return args
