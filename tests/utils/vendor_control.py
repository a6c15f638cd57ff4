"""Control for a real vendor file in the tests: five points about the scene, imaged by the
file's own RPC (independent of our exact model), written as the files ``pba job`` and the web
page read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

WORLDVIEW = Path(__file__).resolve().parents[1] / "data" / "vendor" / "stereopipeline" / "wv_mvp_1.xml"


def write_rpc_control(sensor: Path, folder: Path, image: str) -> None:
    """``folder/IMAGE.csv`` (point, line, column) and ``folder/gcps.csv`` (id, lon, lat, z;
    EPSG:4979) of five points at the RPC's height offset, spread over the middle of its ground
    extent, measured where the Maxar file's RPC puts them."""
    from solver.sensors.maxar import read_maxar

    r = read_maxar(sensor).rpc
    ground = np.column_stack([r.long_off + 0.2 * r.long_scale * np.array([-1, 0, 1, 0.5, -0.5]),
                              r.lat_off + 0.2 * r.lat_scale * np.array([0, 1, -1, 0.5, -0.5]), np.full(5, r.height_off)])
    lc = np.column_stack(r.project(ground[:, 0], ground[:, 1], ground[:, 2]))
    (folder / f"{image}.csv").write_text("point,line,column\n" + "".join(f"G{k},{x[0]:.3f},{x[1]:.3f}\n" for k, x in enumerate(lc)))
    (folder / "gcps.csv").write_text("id,lon,lat,z\n" + "".join(f"G{k},{g[0]:.9f},{g[1]:.9f},{g[2]:.3f}\n" for k, g in enumerate(ground)))
