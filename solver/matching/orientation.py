"""The orientation that guides matching: each image's ground <-> image model, and the
prediction of where a pixel of one image lies in another.

Sources:

- a job (``--job``), with its report (the adjusted orientation) or without (the job's
  initial orientation, as the adjustment starts from it): :class:`solver.gis.model.AdjustedModel`,
  whose images (rigorous or RPC) have ``ground_to_image`` / ``image_to_ground`` (ECEF metres,
  ellipsoidal heights);
- rasters carrying RPCs (GeoTIFF RPC tags or a sidecar GDAL reads: ``NAME_RPC.TXT``, ``.RPB``):
  :class:`solver.gis.rpc_image.RpcImage` with no bias.

:class:`PairMapping` predicts image b's (line, column) of image a's pixels on a grid of a at a
few ellipsoidal heights spanning the terrain (bilinear between grid nodes, linear between
heights): the segment between the lowest and the highest height is the epipolar segment the
match must lie on.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from solver.matching.raster import Raster, RasterError

GRID_NODES = 17  # nodes of the prediction grid along each image axis
N_HEIGHTS = 3  # heights of the prediction grid (lowest, middle, highest)


class ImageModel(Protocol):
    def ground_to_image(self, ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def image_to_ground(self, line: np.ndarray, column: np.ndarray, height_m: Any = None) -> np.ndarray: ...


@dataclass
class MatchImage:
    """One image to match: its id (the job's), raster and ground <-> image model."""

    id: str
    raster: Raster
    model: ImageModel

    @property
    def lines(self) -> int:
        return self.raster.lines

    @property
    def columns(self) -> int:
        return self.raster.columns


class OrientationError(ValueError):
    """The images cannot be oriented (no job and no RPC, unknown ids, sizes that disagree)."""


def _split_arg(arg: str) -> tuple[str | None, Path]:
    """``ID=PATH`` or ``PATH``."""
    if "=" in arg and not Path(arg).exists():
        name, path = arg.split("=", 1)
        return name, Path(path)
    return None, Path(arg)


def _id_of(path: Path, ids: list[str]) -> str | None:
    """The job's image id a raster's name designates: the stem itself, or the stem ending with
    ``.ID``, ``_ID`` or ``-ID`` (``pba simulate --raster`` writes ``<job>.<id>.tif``); the
    longest such id wins."""
    stem = re.sub(r"\.(tiff?|jp2|ntf|img)$", "", path.name, flags=re.I)
    found = [i for i in ids if stem == i or any(stem.endswith(sep + i) for sep in "._-")]
    return max(found, key=len) if found else None


def images_from_rpcs(args: list[str]) -> tuple[list[MatchImage], tuple[float, float]]:
    """Images oriented by their own RPCs, and the height range their RPCs span (each RPC's
    height offset +- its scale, :func:`rpc_height_range`)."""
    from solver.geometry.rpc import RPC, RpcBias
    from solver.gis.rpc_image import RpcImage

    out: list[MatchImage] = []
    for arg in args:
        name, path = _split_arg(arg)
        raster = Raster.open(path)
        if raster.rpcs is None:
            raise OrientationError(f"{path}: the raster has no RPC (no RPC tags, no _RPC.TXT or .RPB beside it): give --job JOB.json")
        try:
            rpc = RPC.from_gdal(raster.rpcs)
        except (KeyError, ValueError) as exc:
            raise OrientationError(f"{path}: incomplete RPC: {exc}") from None
        image_id = name or re.sub(r"\.(tiff?|jp2|ntf|img)$", "", path.name, flags=re.I)
        model = RpcImage(image_id, rpc, RpcBias(), "RPC").with_size(raster.lines, raster.columns)
        out.append(MatchImage(image_id, raster, model))
    _unique_ids(out)
    return out, rpc_height_range([im.model.rpc for im in out])


def rpc_height_range(rpcs: list[Any]) -> tuple[float, float]:
    """The ellipsoidal height range (m) the RPCs span: each RPC's height offset +- its height
    scale (the range the vendor fitted it over, which holds the scene's terrain), joined over
    the images. Matching searches the whole range; a DEM narrows it (``--dem``)."""
    return float(min(r.height_off - abs(r.height_scale) for r in rpcs)), float(max(r.height_off + abs(r.height_scale) for r in rpcs))


def images_from_job(job: dict[str, Any], report: dict[str, Any] | None, args: list[str]) -> tuple[list[MatchImage], tuple[float, float]]:
    """Images oriented by a job (and its report), and the height range of its points +- 100 m.

    A job whose images are all RPC images (``images[].rpc``) needs no adjustment's preparation:
    the delivered RPCs plus the report's bias (none without a report) orient them, and the
    height range is the RPCs' (:func:`rpc_height_range`). So a job composed from RPC images
    alone, before any measurement, can guide the matching (``pba job --rpc ... --match ...``)."""
    from solver.gis.rpc_image import RpcImage

    models, heights = _rpc_job_images(job, report)
    if models is None:
        from solver.gis.model import load_model

        model = load_model(job, report)
        models = {i: model.image(i) for i in model.image_ids}
        heights = model.height_range_m()
    ids = list(models)
    out: list[MatchImage] = []
    for arg in args:
        name, path = _split_arg(arg)
        image_id = name or _id_of(path, ids)
        if image_id is None or image_id not in ids:
            raise OrientationError(
                f"{path}: which image of the job is it? Name it ID={path} (the job's images: {', '.join(ids)})"
            )
        raster = Raster.open(path)
        img = models[image_id]
        if isinstance(img, RpcImage):
            img = img.with_size(raster.lines, raster.columns)
        elif (img.lines, img.columns) != (raster.lines, raster.columns):
            raise OrientationError(
                f"{path}: the raster has {raster.lines} lines x {raster.columns} columns, image {image_id!r} of the job {img.lines} x {img.columns}"
            )
        out.append(MatchImage(image_id, raster, img))
    _unique_ids(out)
    return out, heights


def _rpc_job_images(job: dict[str, Any], report: dict[str, Any] | None) -> tuple[dict[str, Any] | None, tuple[float, float]]:
    """({id: RpcImage}, height range) of a job whose images are all RPC images; (None, _)
    otherwise (the caller prepares the job as the adjustment does)."""
    from solver.gis.model import ModelMismatch
    from solver.gis.rpc_image import rpc_image

    entries = job.get("images") if isinstance(job, dict) else None
    if not entries or not all(isinstance(e, dict) and isinstance(e.get("rpc"), dict) and isinstance(e.get("id"), str) for e in entries):
        return None, (0.0, 0.0)
    reported = {e.get("id"): e for e in (report or {}).get("images", [])}
    models: dict[str, Any] = {}
    for e in entries:
        if report is not None:
            entry = reported.get(e["id"])
            model = (e.get("model") or {}).get("name") if isinstance(e.get("model"), dict) else e.get("model")
            if entry is None:
                raise ModelMismatch(f"image {e['id']!r} of the job is not in the report")
            if entry.get("model") != model:
                raise ModelMismatch(f"image {e['id']!r}: the report's model is {entry.get('model')!r}, the job's {model!r}")
        try:
            models[e["id"]] = rpc_image(e, reported.get(e["id"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise OrientationError(f"image {e['id']!r}: unusable rpc: {exc}") from None
    return models, rpc_height_range([m.rpc for m in models.values()])


def _unique_ids(images: list[MatchImage]) -> None:
    seen: set[str] = set()
    for im in images:
        if im.id in seen:
            raise OrientationError(f"image {im.id!r} is given twice")
        seen.add(im.id)


def _axis(n: int) -> np.ndarray:
    return np.linspace(0.0, n - 1.0, GRID_NODES)


class PairMapping:
    """Where image a's pixels lie in image b (module docstring): b's (line, column) on a grid
    of a's pixels at the heights :attr:`heights` (ellipsoidal metres)."""

    def __init__(self, a: MatchImage, b: MatchImage, heights: tuple[float, float]):
        self.a, self.b = a, b
        self.heights = np.linspace(heights[0], heights[1], N_HEIGHTS)
        self.ls, self.cs = _axis(a.lines), _axis(a.columns)
        ll, cc = np.meshgrid(self.ls, self.cs, indexing="ij")
        bl = np.full((N_HEIGHTS,) + ll.shape, np.nan)
        bc = np.full_like(bl, np.nan)
        with np.errstate(all="ignore"):
            for k, h in enumerate(self.heights):
                ground = a.model.image_to_ground(ll.ravel(), cc.ravel(), height_m=float(h))
                line, col, _chip = b.model.ground_to_image(ground)
                bl[k] = np.asarray(line, float).reshape(ll.shape)
                bc[k] = np.asarray(col, float).reshape(ll.shape)
        self._both = np.stack([bl, bc])  # (2, heights, lines, columns): one interpolation for both
        self.bl, self.bc = self._both[0], self._both[1]
        self._mid: np.ndarray | None = None  # (2, lines, columns) b's line and column at the middle height (jacobian)

    def _bilinear(self, grid: np.ndarray, line: np.ndarray, column: np.ndarray) -> np.ndarray:
        ls, cs = self.ls, self.cs
        i = np.clip(np.searchsorted(ls, line, side="right") - 1, 0, len(ls) - 2)
        j = np.clip(np.searchsorted(cs, column, side="right") - 1, 0, len(cs) - 2)
        fr = (line - ls[i]) / (ls[i + 1] - ls[i])
        fc = (column - cs[j]) / (cs[j + 1] - cs[j])
        return (grid[..., i, j] * (1 - fr) * (1 - fc) + grid[..., i, j + 1] * (1 - fr) * fc
                + grid[..., i + 1, j] * fr * (1 - fc) + grid[..., i + 1, j + 1] * fr * fc)

    def at_heights(self, line: np.ndarray, column: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """b's (line, column), each (N_HEIGHTS, n), of a's points at every grid height."""
        line = np.atleast_1d(np.asarray(line, float))
        column = np.atleast_1d(np.asarray(column, float))
        both = self._bilinear(self._both, line, column)
        return both[0], both[1]

    def segment(self, line: np.ndarray, column: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The epipolar segments of a's points in b: (n, 2) ends at the lowest and highest height."""
        bl, bc = self.at_heights(line, column)
        return np.column_stack([bl[0], bc[0]]), np.column_stack([bl[-1], bc[-1]])

    def at_height(self, line: np.ndarray, column: np.ndarray, height: np.ndarray | float) -> np.ndarray:
        """(n, 2) b's (line, column) of a's points at ellipsoidal ``height`` (m, one or one per
        point): linear between the grid heights, extended beyond the lowest and the highest."""
        bl, bc = self.at_heights(line, column)
        h = np.broadcast_to(np.asarray(height, float), bl.shape[1:])
        k = np.clip(np.searchsorted(self.heights, h, side="right") - 1, 0, N_HEIGHTS - 2)
        f = (h - self.heights[k]) / (self.heights[k + 1] - self.heights[k])
        n = np.arange(bl.shape[1])
        return np.column_stack([bl[k, n] + f * (bl[k + 1, n] - bl[k, n]), bc[k, n] + f * (bc[k + 1, n] - bc[k, n])])

    def height_of(self, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
        """(n,) the ellipsoidal height (m, within the range) at which a's points ``pa`` (n, 2)
        fall nearest to b's ``pb`` (n, 2): ``pb`` projected on the epipolar curve (straight
        between the grid heights)."""
        bl, bc = self.at_heights(pa[:, 0], pa[:, 1])
        best = np.full(len(pa), np.inf)
        out = np.full(len(pa), np.nan)
        with np.errstate(all="ignore"):
            for k in range(N_HEIGHTS - 1):
                p0 = np.column_stack([bl[k], bc[k]])
                d = np.column_stack([bl[k + 1], bc[k + 1]]) - p0
                t = np.clip(np.sum((pb - p0) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-12), 0.0, 1.0)
                dist = np.hypot(*(pb - p0 - t[:, None] * d).T)
                nearer = dist < best
                best = np.where(nearer, dist, best)
                out = np.where(nearer, self.heights[k] + t * (self.heights[k + 1] - self.heights[k]), out)
        return out

    def jacobian(self, line: float, column: float, step: float = 4.0) -> np.ndarray:
        """2 x 2 d(b line, b column) / d(a line, a column) at the middle height."""
        return self.jacobians(np.array([line], float), np.array([column], float), step)[0]

    def jacobians(self, line: np.ndarray, column: np.ndarray, step: float = 4.0) -> np.ndarray:
        """(n, 2, 2) :meth:`jacobian` at each of a's points: central differences of ``step`` px
        of b's position at the middle height."""
        k = N_HEIGHTS // 2
        line, column = np.atleast_1d(np.asarray(line, float)), np.atleast_1d(np.asarray(column, float))
        lv = np.concatenate([line - step, line + step, line, line])
        cv = np.concatenate([column, column, column - step, column + step])
        if self._mid is None:
            self._mid = np.stack([self.bl[k], self.bc[k]])
        bl, bc = self._bilinear(self._mid, lv, cv).reshape(2, 4, -1)
        return np.stack([np.stack([bl[1] - bl[0], bl[3] - bl[2]], -1), np.stack([bc[1] - bc[0], bc[3] - bc[2]], -1)], -2) / (2 * step)

    def reaches_b(self, line: np.ndarray, column: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """(n,) whether a's points fall inside b (``margin_px`` from its border) at some height
        of the range: their epipolar curve (straight between the grid heights) enters b."""
        bl, bc = self.at_heights(line, column)
        return self._enters_b(bl, bc, margin_px)

    def _enters_b(self, bl: np.ndarray, bc: np.ndarray, margin_px: float) -> np.ndarray:
        lo = np.array([margin_px, margin_px])
        hi = np.array([self.b.lines - 1 - margin_px, self.b.columns - 1 - margin_px])
        ends = np.stack([bl, bc], -1)  # (heights, ..., 2)
        return segment_enters_box(ends[:-1], ends[1:], lo, hi).any(axis=0)  # every height step at once

    def overlap_fraction(self, margin_px: float = 0.0) -> float:
        """Fraction of a's grid nodes that fall inside b at some height of the range."""
        return float(self._enters_b(self.bl, self.bc, margin_px).mean())


def segment_enters_box(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(...,) whether segments p0-p1 (..., 2) meet the box lo <= p <= hi (Liang-Barsky clipping);
    a segment with a non-finite end never does."""
    with np.errstate(all="ignore"):
        d = p1 - p0
        t0 = np.zeros(p0.shape[:-1])
        t1 = np.ones(p0.shape[:-1])
        ok = np.all(np.isfinite(p0), -1) & np.all(np.isfinite(p1), -1)
        for ax in range(2):
            still = np.abs(d[..., ax]) < 1e-12
            ok &= ~still | ((p0[..., ax] >= lo[ax]) & (p0[..., ax] <= hi[ax]))
            ta = (lo[ax] - p0[..., ax]) / d[..., ax]
            tb = (hi[ax] - p0[..., ax]) / d[..., ax]
            t0 = np.where(still, t0, np.maximum(t0, np.minimum(ta, tb)))
            t1 = np.where(still, t1, np.minimum(t1, np.maximum(ta, tb)))
    return ok & (t0 <= t1)


def distance_to_segment(p: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(perpendicular signed distance, along-segment distance beyond its ends) of points p (n, 2)
    from segments s0-s1 (n, 2) or (2,) each; pixels. A zero-length segment's direction is the
    line axis."""
    d = s1 - s0
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    u = np.where(length > 1e-9, d / np.maximum(length, 1e-9), np.array([1.0, 0.0]))
    v = p - s0
    t = np.sum(v * u, axis=-1)
    perp = v[..., 0] * u[..., 1] - v[..., 1] * u[..., 0]
    beyond = np.maximum(np.maximum(-t, t - length[..., 0]), 0.0)
    return perp, beyond


def height_range_arg(text: str, option: str = "--heights") -> tuple[float, float]:
    """``MIN,MAX`` ellipsoidal metres (``option``: the flag named in the message)."""
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise OrientationError(f"{option} {text!r}: give MIN,MAX in ellipsoidal metres") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise OrientationError(f"{option} {text!r}: MIN must be below MAX")
    return lo, hi


__all__ = ["MatchImage", "OrientationError", "PairMapping", "RasterError", "distance_to_segment", "images_from_job", "images_from_rpcs"]
