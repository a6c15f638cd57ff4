"""The exact model against the vendor's RPC of the same image, and the stereo check of a pair.

:func:`rpc_agreement`: over a grid of image positions (``n`` x ``n`` lines and columns spanning
the image, edges included) times heights (the RPC's height offset +- its scale at ``k`` levels),
each image position is taken to the ground by the exact model at that height and back into the
image by the RPC: residuals in pixels (line, column; RMS, mean, maximum of the 2-D distance).
:func:`correction_sizes`: how far each correction moves the exact model's ground-to-image (px),
each switched off alone. :func:`stereo_closure`: ground points projected into two images by the
vendor's RPCs and intersected back with the exact models: the distance to where they started.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np

from solver.geometry.geodesy import LocalFrame, geodetic_to_ecef
from solver.geometry.rpc import RPC
from solver.sensors.linescan import Corrections, LinescanModel


def image_grid(model: LinescanModel, rpc: RPC, n: int = 11, k: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(line, column, height_m) of the comparison grid (module docstring)."""
    lines = np.linspace(0, model.lines - 1, n)
    cols = np.linspace(0, model.columns - 1, n)
    heights = rpc.height_off + rpc.height_scale * np.linspace(-1, 1, k)
    L, C, H = np.meshgrid(lines, cols, heights, indexing="ij")
    return L.ravel(), C.ravel(), H.ravel()


def _stats(dl: np.ndarray, dc: np.ndarray) -> dict[str, float]:
    d = np.hypot(dl, dc)
    return {
        "rms_px": float(np.sqrt(np.mean(d * d))), "max_px": float(d.max()),
        "line_mean_px": float(dl.mean()), "line_rms_px": float(np.sqrt(np.mean(dl * dl))),
        "column_mean_px": float(dc.mean()), "column_rms_px": float(np.sqrt(np.mean(dc * dc))),
    }


def rpc_agreement(model: LinescanModel, rpc: RPC, n: int = 11, k: int = 5) -> dict[str, Any]:
    """Residuals (px) of RPC(exact image-to-ground(grid)) - grid, and the grid's size."""
    L, C, H = image_grid(model, rpc, n, k)
    g = model.image_to_ground(L, C, H)
    rl, rc = rpc.project(g[:, 0], g[:, 1], g[:, 2])
    out = _stats(rl - L, rc - C)
    out.update({"points": int(L.size), "image_positions": n * n, "heights_m": [float(h) for h in np.unique(H)]})
    return out


def correction_sizes(model: LinescanModel, rpc: RPC, n: int = 11, k: int = 5) -> dict[str, dict[str, float]]:
    """For each correction: the RPC agreement without it, and how far it moves image positions
    (RMS and maximum px of the exact ground-to-image with minus without it, on the same ground
    points)."""
    L, C, H = image_grid(model, rpc, n, k)
    out: dict[str, dict[str, float]] = {}
    for f in fields(Corrections):
        off = model.with_corrections(**{f.name: False})
        g = off.image_to_ground(L, C, H)
        moved = model.ground_to_image(g) - np.column_stack([L, C])
        d = np.hypot(moved[:, 0], moved[:, 1])
        rl, rc = rpc.project(g[:, 0], g[:, 1], g[:, 2])
        without = _stats(rl - L, rc - C)
        out[f.name] = {"shift_rms_px": float(np.sqrt(np.nanmean(d * d))), "shift_max_px": float(np.nanmax(d)),
                       "rpc_rms_px_without": without["rms_px"], "rpc_max_px_without": without["max_px"]}
    return out


def intersect(models: list[LinescanModel], image_points: list[np.ndarray], start: np.ndarray, iterations: int = 10) -> np.ndarray:
    """Geodetic points (lon_deg, lat_deg, h_m) (n, 3) seen at ``image_points[i]`` ((n, 2) line,
    column) in every model: Gauss-Newton on (lon, lat, h) of the image residuals of the exact
    ground-to-image, from ``start`` (n, 3)."""
    x = np.array(start, float)
    steps = np.array([1e-6, 1e-6, 1.0])
    for _ in range(iterations):
        r, j = [], []
        for m, obs in zip(models, image_points):
            p0 = m.ground_to_image(x)
            r.append(obs - p0)
            j.append(np.stack([(m.ground_to_image(x + np.eye(3)[a] * steps[a]) - p0) / steps[a] for a in range(3)], axis=2))
        res = np.concatenate(r, axis=1)[:, :, None]  # (n, 2m, 1)
        jac = np.concatenate(j, axis=1)  # (n, 2m, 3)
        jt = np.transpose(jac, (0, 2, 1))
        delta = np.linalg.solve(jt @ jac, jt @ res)[:, :, 0]
        x = x + delta
        if np.all(np.abs(delta[:, 2]) < 1e-4):
            break
    return x


def stereo_closure(models: list[LinescanModel], rpcs: list[RPC], ground: np.ndarray) -> dict[str, Any]:
    """Ground points (lon, lat, h) projected by the RPCs into each image and intersected back with
    the exact models (started 100 m above and 1e-4 degrees away): distances in metres (3-D RMS and
    maximum, horizontal and vertical RMS)."""
    obs = [np.column_stack(r.project(ground[:, 0], ground[:, 1], ground[:, 2])) for r in rpcs]
    x = intersect(models, obs, ground + np.array([1e-4, -1e-4, 100.0]))
    frame = LocalFrame.at_centroid(geodetic_to_ecef(ground))
    d = frame.to_lgs(geodetic_to_ecef(x)) - frame.to_lgs(geodetic_to_ecef(ground))
    d3 = np.linalg.norm(d, axis=1)
    return {"points": int(ground.shape[0]), "rms_3d_m": float(np.sqrt(np.mean(d3**2))), "max_3d_m": float(d3.max()),
            "horizontal_rms_m": float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))),
            "vertical_rms_m": float(np.sqrt(np.mean(d[:, 2] ** 2)))}
