"""GeoJSON of a finished job (RFC 7946: WGS 84 longitude, latitude in degrees, CRS84).

Features (``properties.kind``):

- ``footprint``: one Polygon per image, its border (every image edge sampled at 8 points)
  intersected with the mean ellipsoidal height of the job's points by the adjusted model;
  properties ``image``, ``model``, ``height_m``.
- ``control`` / ``check`` / ``tie``: one Point per ground point (control and check at their known
  coordinates, tie points at their adjusted ones), properties ``id``, ``role``, ``height_m``,
  ``residuals_px`` (per image: ``image``, ``line``, ``column`` residual in pixels, observed minus
  adjusted) and ``rms_residual_px``; check points add ``discrepancy_m`` (``e``, ``n``, ``u``,
  ``planimetric``: estimated minus known, metres), weighted control points ``correction_m``
  (``e``, ``n``, ``u``); tie points ``sigma_m`` (``e``, ``n``, ``u``: predicted precision,
  a posteriori).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic
from solver.gis.model import AdjustedModel

EDGE_SAMPLES = 8


def footprint(model: AdjustedModel, image_id: str, height_m: float) -> list[list[float]]:
    """Closed ring (lon, lat) of an image's border on the ellipsoidal height ``height_m``."""
    img = model.image(image_id)
    lmax, cmax = img.lines - 0.5, img.columns - 0.5
    t = np.linspace(0.0, 1.0, EDGE_SAMPLES, endpoint=False)
    line = np.concatenate([np.full_like(t, -0.5), -0.5 + t * (lmax + 0.5), np.full_like(t, lmax), lmax - t * (lmax + 0.5)])
    col = np.concatenate([-0.5 + t * (cmax + 0.5), np.full_like(t, cmax), cmax - t * (cmax + 0.5), np.full_like(t, -0.5)])
    # the outermost pixel centres (chips cover -0.5 .. columns - 0.5 inclusive)
    col = np.clip(col, -0.5, cmax)
    ecef = img.image_to_ground(line, col, height_m)
    llh = ecef_to_geodetic(ecef[np.all(np.isfinite(ecef), axis=1)])
    ring = [[float(x), float(y)] for x, y in llh[:, :2]]
    if ring:
        ring.append(ring[0])
    return ring


def _residuals(report: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for o in report.get("observations") or []:
        out.setdefault(o["point"], []).append(
            {"image": o["image"], "line": o.get("residual_line_px"), "column": o.get("residual_column_px")}
        )
    return out


def _rms(items: list[dict[str, Any]]) -> float | None:
    v = [x for it in items for x in (it["line"], it["column"]) if x is not None]
    return float(np.sqrt(np.mean(np.square(v)) * 2.0)) if v else None  # per point: sqrt(dl^2 + dc^2)


def results_geojson(model: AdjustedModel) -> dict[str, Any]:
    """The FeatureCollection described in the module docstring."""
    report = model.report
    problem = model.problem
    frame = problem.frame
    features: list[dict[str, Any]] = []
    known = [p for p in problem.points if p.known_lgs is not None]
    mean_h = 0.0
    if known:
        mean_h = float(np.mean(ecef_to_geodetic(frame.to_ecef(np.array([p.known_lgs for p in known])))[:, 2]))
    for img in problem.images:
        ring = footprint(model, img.id, mean_h)
        features.append({
            "type": "Feature",
            "geometry": {"type": "Polygon", "coordinates": [ring]},
            "properties": {"kind": "footprint", "image": img.id, "model": img.model.name, "height_m": mean_h},
        })
    residuals = _residuals(report)
    checks = {c["id"]: c for c in (report.get("checkpoints") or {}).get("points") or []}
    gcps = {c["id"]: c for c in report.get("control_points") or []}
    ties = {c["id"]: c for c in report.get("tie_points") or []}
    for p in problem.points:
        props: dict[str, Any] = {"id": p.id, "role": p.role}
        if p.role == "tie":
            t = ties.get(p.id)
            if t is None:
                continue
            lon, lat, h = t["lon_deg"], t["lat_deg"], t["height_m"]
            props["kind"] = "tie"
            props["sigma_m"] = None if t.get("sigma_m") is None else dict(zip("enu", t["sigma_m"]))
        elif p.known_lgs is not None:
            lon, lat, h = (float(x) for x in ecef_to_geodetic(frame.to_ecef(p.known_lgs[None, :]))[0])
            props["kind"] = "check" if p.role == "check" else "control"
            if p.role == "check" and p.id in checks:
                props["discrepancy_m"] = checks[p.id].get("discrepancy_m")
            if p.id in gcps and gcps[p.id].get("correction_m") is not None:
                props["correction_m"] = dict(zip("enu", gcps[p.id]["correction_m"]))
        else:
            continue
        props["height_m"] = h
        props["residuals_px"] = residuals.get(p.id, [])
        props["rms_residual_px"] = _rms(props["residuals_px"])
        features.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": [lon, lat]}, "properties": props})
    return {"type": "FeatureCollection", "name": report.get("job_name"), "features": features}
