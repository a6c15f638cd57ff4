"""Jobs of the simulated SPOT 1-4 scene (tests/solver/sensors/simulated_spot14.py): the job the
reader composes from its METADATA.DIM, with control and check points imaged by the scene's
truth, for the tests of the reader, the self-check and the control check."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
from monte_carlo import perturbed
from simulated_spot14 import Spot14Scene, metadata_dim

from solver.sensors.dimap_spot5 import read_spot5

SURVEY_M = 0.5  # the control and check points' sigma (and noise, when perturbed)
IMAGE_PX = 0.3  # the image measurements' sigma (and noise, when perturbed)


def product(folder: Path, scene: Spot14Scene | None = None):  # noqa: ANN201 (a Spot5Product)
    """The scene (default: :class:`Spot14Scene`), its METADATA.DIM in ``folder``, and the product read from it."""
    scene = scene or Spot14Scene()
    path = folder / "METADATA.DIM"
    path.write_text(metadata_dim(scene))
    return scene, path, read_spot5(path)


def truth_job(scene: Spot14Scene, p, gcps: int, checks: int, seed: int, perturb: bool) -> dict:  # noqa: ANN001
    """The fragment of ``p`` with ``gcps`` control and ``checks`` check points imaged by the
    scene's truth at 0-2000 m; with ``perturb`` every observation perturbed as its weight says
    (the survey by SURVEY_M east, north and up)."""
    from solver.sensors.job_fragment import fragment

    doc = fragment([p], ["S"])
    doc.pop("sensor_metadata")
    g = np.random.default_rng(seed)
    n = gcps + checks
    L, C, H = g.uniform(60, scene.lines - 60, n), g.uniform(60, scene.columns - 60, n), g.uniform(0, 2000, n)
    ground = scene.geodetic(scene.ground(L, C, H))
    points = [{"id": f"P{k}", "role": "gcp" if k < gcps else "check", "coordinates": [float(v) for v in ground[k]],
               "sigma_m": [SURVEY_M] * 3} for k in range(n)]
    obs = [{"image": "S", "point": f"P{k}", "line": float(L[k]), "column": float(C[k]), "sigma_px": IMAGE_PX} for k in range(n)]
    if perturb:
        doc, obs = perturbed(doc, obs, g)
        lat = np.radians(ground[:, 1])
        for k, q in enumerate(points):  # east and north metres as degrees at the point's latitude
            de, dn, du = g.normal(0, SURVEY_M, 3)
            q["coordinates"] = [q["coordinates"][0] + np.degrees(de / (6378137.0 * np.cos(lat[k]))),
                                q["coordinates"][1] + np.degrees(dn / 6378137.0), q["coordinates"][2] + du]
    return {"schema_version": "1.0", "name": "spot14", "crs": "EPSG:4326", **doc, "points": points, "observations": obs}


def foreign(scene, job: dict, shift: float = 5700.0) -> dict:
    """The control of a neighbouring image: each control point measured where it is, but its
    ground the scene's at ``shift`` columns further right (beyond this image's edge, where the
    neighbour sees it); check points kept."""
    bad = copy.deepcopy(job)
    pts = {p["id"]: p for p in bad["points"] if p["role"] == "gcp"}
    for o in bad["observations"]:
        if o["point"] in pts:
            p = pts[o["point"]]
            g = scene.geodetic(scene.ground(np.array([o["line"]]), np.array([o["column"] + shift]), np.array([p["coordinates"][2]])))
            p["coordinates"] = [float(g[0, 0]), float(g[0, 1]), p["coordinates"][2]]
    return bad
