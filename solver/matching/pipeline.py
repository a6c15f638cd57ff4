"""Tie points of a set of oriented images: the steps of matching and their summary.

1. pairs: images whose footprints (over the lowest and the highest terrain height) intersect,
   then the fraction of the first image's prediction grid that falls in the second at some
   height of the range;
2. SIFT matches in the predicted band of every pair (:mod:`solver.matching.features`);
3. tracks linked over pairs, thinned to ``per_cell`` per image cell (:mod:`solver.matching.tracks`);
4. sub-pixel positions by correlation against the track's reference image and the epipolar
   check of every pair, with each pair's precision (:mod:`solver.matching.refine`);
4b. tracks of three or more images checked in 3-D against the orientation with a per-image
   bias (:mod:`solver.matching.verify`): blunders along the epipolar lines removed, and each
   image's stated sigmas in such tracks scaled to what their 3-D residuals show;
5. the measurements (``image, point, line, column, sigma_px``), sorted by point then image order.

Deterministic: no randomness but OpenCV's RANSAC with a fixed seed; images in the order given,
pairs (i < j) in order, tracks in their reference position's order.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from solver.engine.heap import release_freed_memory
from solver.matching.features import MatchSettings, PairMatches, detection_scale, match_pair, tiles
from solver.matching.keypoints import FeatureCache, detection_pool, match_threads
from solver.matching.orientation import MatchImage, PairMapping
from solver.matching.refine import REFERENCE_SIGMA_PX, SIGMA_FLOOR_PX, epipolar_check, other_sigma, refine_tracks
from solver.matching.tracks import cell_of, link, thin

Progress = Callable[[float, str], None]
FOOTPRINT_NODES = 9  # points per image edge for the footprint pre-selection of pairs
MIN_OVERLAP = 0.004  # fraction of the prediction grid (at least ~1 node of 17 x 17)
CORRELATION_BATCH = 128  # tracks correlated together (memory: a window of about 8 kB per image of each)


class MatchError(ValueError):
    """Matching cannot start or found nothing (the message says why and what to try);
    ``summary``: what was found up to there (the pairs tried and their overlap)."""

    def __init__(self, message: str, summary: dict[str, Any] | None = None):
        super().__init__(message)
        self.summary = summary


@dataclass
class MatchResult:
    measurements: list[dict[str, Any]]
    summary: dict[str, Any]


def _footprint_box(image: MatchImage, height: float) -> np.ndarray | None:
    """(lon min, lat min, lon max, lat max) of the image's border on the ground at ``height``."""
    from solver.geometry.geodesy import ecef_to_geodetic

    t = np.linspace(0, 1, FOOTPRINT_NODES)
    L, C = image.lines - 1.0, image.columns - 1.0
    line = np.concatenate([t * L, t * L, np.zeros_like(t), np.full_like(t, L)])
    col = np.concatenate([np.zeros_like(t), np.full_like(t, C), t * C, t * C])
    with np.errstate(all="ignore"):
        llh = ecef_to_geodetic(image.model.image_to_ground(line, col, height_m=height))
    ok = np.all(np.isfinite(llh), axis=1)
    if not ok.any():
        return None
    return np.array([llh[ok, 0].min(), llh[ok, 1].min(), llh[ok, 0].max(), llh[ok, 1].max()])


def _union(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    if a is None or b is None:
        return b if a is None else a
    return np.concatenate([np.minimum(a[:2], b[:2]), np.maximum(a[2:], b[2:])])


def candidate_pairs(images: list[MatchImage], heights: tuple[float, float]) -> list[tuple[int, int]]:
    """Pairs (i < j) whose footprint boxes, each the union of the boxes at the lowest and the
    highest height, intersect."""
    boxes = [_union(_footprint_box(im, heights[0]), _footprint_box(im, heights[1])) for im in images]
    out = []
    for i in range(len(images)):
        for j in range(i + 1, len(images)):
            a, b = boxes[i], boxes[j]
            if a is not None and b is not None and a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]:
                out.append((i, j))
    return out


def match_images(images: list[MatchImage], heights: tuple[float, float], settings: MatchSettings = MatchSettings(), progress: Progress | None = None,
                 terrain: Any = None) -> MatchResult:
    """Tie-point measurements and the summary of ``images`` (module docstring), over the
    terrain heights ``heights`` (ellipsoidal m) and each tile's from ``terrain`` (a DEM's:
    :class:`solver.matching.heights.DemHeights`) when given; raises
    :class:`MatchError` when no pair overlaps.

    Threads: :func:`solver.matching.keypoints.match_threads` (``PBA_MATCH_THREADS``) for
    OpenCV's own (inside each SIFT call: the scale space, the extrema and the descriptors are
    computed in parallel; a call made while they are busy runs in its caller's thread alone) and
    for the detection ahead; one for BLAS: the many small products of descriptors are slower
    when BLAS threads have to meet for each (10 times on a loaded machine). The result is the
    same whatever the number of threads (features are sorted, each computed alone). OpenCV's
    thread count is put back afterwards (it is global to the process)."""
    import cv2
    from threadpoolctl import threadpool_limits

    threads = match_threads()
    previous = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        with threadpool_limits(limits=1, user_api="blas"), detection_pool(threads) as pool:
            return _match_images(images, heights, settings, progress, terrain, pool)
    finally:
        cv2.setNumThreads(previous)


def _match_images(images: list[MatchImage], heights: tuple[float, float], settings: MatchSettings, progress: Progress | None, terrain: Any,
                  pool: Executor | None = None) -> MatchResult:
    say = progress or (lambda f, m: None)
    if len(images) < 2:
        raise MatchError("matching needs at least two images")
    say(0.0, "pairs")
    mappings: dict[tuple[int, int], PairMapping] = {}

    def mapping(a: int, b: int) -> PairMapping:
        if (a, b) not in mappings:
            mappings[(a, b)] = PairMapping(images[a], images[b], heights)
        return mappings[(a, b)]

    pairs = []
    overlaps = {}
    tried = []
    for i, j in candidate_pairs(images, heights):
        f = mapping(i, j).overlap_fraction()
        tried.append({"images": [images[i].id, images[j].id], "overlap_fraction": round(f, 3)})
        if f >= MIN_OVERLAP:
            pairs.append((i, j))
            overlaps[(i, j)] = f
    if not pairs:
        raise MatchError(
            f"no two images overlap at any terrain height from {heights[0]:.0f} to {heights[1]:.0f} m "
            f"(images: {', '.join(im.id for im in images)}; {len(tried)} pairs with intersecting footprints); "
            "if they show the same area, give a height range that holds the terrain (--heights MIN,MAX, ellipsoidal) "
            "or an orientation closer to the truth (--job with --report)",
            {"images": [{"id": im.id, "lines": im.lines, "columns": im.columns} for im in images],
             "height_range_m": [float(heights[0]), float(heights[1])], "pairs": [], "pairs_tried": tried,
             "tie_points": 0, "measurements": 0, "settings": asdict(settings)},
        )
    say(0.05, "features")
    settings = detection_scale(images, settings)
    matches: list[PairMatches] = []
    caches: dict[int, FeatureCache] = {}
    detected = [0.0] * len(images)  # the share of each image's pixels SIFT ran on
    last_pair = {k: max(n for n, p in enumerate(pairs) if k in p) for k in {k for p in pairs for k in p}}
    for n, (i, j) in enumerate(pairs):
        def tile_progress(f: float, n=n, i=i, j=j) -> None:
            say(0.05 + 0.75 * (n + f) / len(pairs), f"{images[i].id}-{images[j].id}")

        for k in (i, j):
            caches.setdefault(k, FeatureCache(images[k], settings.decimation, pool))
            if last_pair[k] == n:  # its last pair: keep the blocks of the last four rows of tiles (one window each)
                caches[k].keep_recent(4 * settings.grid)
        for k in pairs[n + 1] if n + 1 < len(pairs) else ():  # the next pair's small images: detected ahead
            caches.setdefault(k, FeatureCache(images[k], settings.decimation, pool)).prefetch_whole()
        matches.append(match_pair(images[i], images[j], i, j, mapping(i, j), settings, caches[i], caches[j], tile_progress, terrain))
        for k in (i, j):
            if last_pair[k] == n:  # the image's features are not needed any more
                detected[k] = caches.pop(k).detected_fraction()
            elif all(p[0] == k for p in pairs[n + 1:] if k in p):  # from now on only its tiles as a are read
                caches[k].retain([(t.lo, t.hi) for t in tiles(images[k], settings)[0]])
        release_freed_memory()  # SIFT's scale spaces freed in the detection thread's heap: back to the system
    tracks, inconsistent = link(matches, len(images), settings.decimation)
    sizes = [(im.lines, im.columns) for im in images]
    kept = thin(tracks, sizes, settings.grid, settings.per_cell)
    say(0.8, "correlation")
    refined = []
    for n in range(0, len(kept), CORRELATION_BATCH):
        say(0.8 + 0.15 * n / max(len(kept), 1), "correlation")
        batch = [t.members for t in kept[n:n + CORRELATION_BATCH]]
        refined += [r for r in refine_tracks(batch, images, mapping, settings.template_half_px, settings.min_ncc, pool) if r]
    release_freed_memory()
    say(0.95, "epipolar check")
    sigmas, removed = _check(refined, images, mapping, settings)
    removed_3d, bias, scale = _verify_3d(refined, images, heights, sigmas)
    stated = _Stated(sigmas, scale)
    measurements = _measurements(refined, images, stated)
    summary = _summary(images, heights, settings, pairs, overlaps, matches, tracks, inconsistent, kept, refined, sigmas, removed, measurements, stated)
    for row, n_removed, b, f, k in zip(summary["images"], removed_3d, bias, detected, scale, strict=True):
        row["detected_fraction"] = round(f, 3)
        row["removed_3d"] = n_removed
        row["bias_px"] = [round(float(b[0]), 3), round(float(b[1]), 3)]
        row["sigma_scale_3d"] = round(float(k), 3)
    say(1.0, "done")
    return MatchResult(measurements, summary)


def _check(refined: list[dict], images, mapping, s: MatchSettings) -> tuple[dict[tuple[int, int], float], dict[tuple[int, int], int]]:
    """Epipolar check of every (reference, other) pair (in place: removed members deleted)."""
    by_pair: dict[tuple[int, int], list[int]] = {}
    for k, r in enumerate(refined):
        ref = min(r)
        for m in r:
            if m != ref:
                by_pair.setdefault((ref, m), []).append(k)
    sigmas, removed = {}, {}
    for (ref, m), ks in sorted(by_pair.items()):
        rp = np.array([refined[k][ref][0] for k in ks])
        mp = np.array([refined[k][m][0] for k in ks])
        keep, sigma, _ = epipolar_check(rp, mp, mapping(ref, m), s.search_px)
        sigmas[(ref, m)] = sigma
        removed[(ref, m)] = int((~keep).sum())
        for k, ok in zip(ks, keep, strict=True):
            if not ok:
                del refined[k][m]
    for k, r in enumerate(refined):
        if len(r) < 2:
            refined[k] = {}
    refined[:] = [r for r in refined if r]
    return sigmas, removed


class _Stated:
    """The sigma (px) written for each measurement: the reference's convention, the pair's
    (:func:`other_sigma` of its epipolar scatter) for the others, times the image's factor from
    the 3-D residuals (:func:`solver.matching.verify.sigma_scales`) in a tie point of three or
    more images (where the 3-D check measured it), at least the pair's floor."""

    def __init__(self, sigmas: dict[tuple[int, int], float], scale: np.ndarray):
        self.sigmas, self.scale = sigmas, scale

    def __call__(self, r: dict, m: int) -> float:
        ref = min(r)
        if m == ref:
            return REFERENCE_SIGMA_PX
        sigma = other_sigma(self.sigmas[(ref, m)])
        if len(r) >= 3:
            sigma = max(sigma * float(self.scale[m]), other_sigma(SIGMA_FLOOR_PX))
        return sigma


def _verify_3d(refined: list[dict], images: list[MatchImage], heights: tuple[float, float], sigmas: dict[tuple[int, int], float]) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Tracks of three or more images checked in 3-D (:mod:`solver.matching.verify`; in place:
    removed members deleted, tracks left with one member dropped): the measurements removed per
    image, each image's bias against the tracks (pixels) and the factor of its stated sigmas the
    kept measurements' 3-D residuals ask for."""
    from solver.matching.verify import sigma_scales, verify

    tracks = [{m: np.asarray(v[0], float) for m, v in r.items()} for r in refined]
    stated = [{m: REFERENCE_SIGMA_PX if m == min(r) else other_sigma(sigmas[(min(r), m)]) for m in r} for r in refined]
    sizes = [(im.lines, im.columns) for im in images]
    gone, bias, _res = verify(tracks, stated, [im.model for im in images], heights, sizes)
    counts = [0] * len(images)
    for r, g in zip(refined, gone, strict=True):
        for m in g:
            del r[m]
            counts[m] += 1
    refined[:] = [r for r in refined if len(r) >= 2]
    kept = [{m: np.asarray(v[0], float) for m, v in r.items()} for r in refined]
    kept_stated = [{m: REFERENCE_SIGMA_PX if m == min(r) else other_sigma(sigmas[(min(r), m)]) for m in r} for r in refined]
    scale = sigma_scales(kept, kept_stated, [im.model for im in images], heights, bias, sizes)
    return counts, np.array([bias[i][0] for i in range(len(images))]), scale  # the shift (line, column) at the image's centre


def _measurements(refined: list[dict], images: list[MatchImage], stated: _Stated) -> list[dict[str, Any]]:
    width = max(5, len(str(len(refined))))
    out = []
    for n, r in enumerate(refined):
        point = f"M{n + 1:0{width}d}"
        for m in sorted(r):
            pos, _ncc = r[m]
            sigma = stated(r, m)
            out.append({"image": images[m].id, "point": point, "line": round(float(pos[0]), 3), "column": round(float(pos[1]), 3), "sigma_px": round(sigma, 3)})
    return out


def measurements_csv(measurements: list[dict[str, Any]]) -> str:
    """The measurement table the importers read (:mod:`solver.importers.measurements_csv`):
    ``image,point,line,column,sigma_px``, pixels in our convention."""
    rows = ["image,point,line,column,sigma_px"]
    rows += [f"{m['image']},{m['point']},{m['line']:.3f},{m['column']:.3f},{m['sigma_px']:.3f}" for m in measurements]
    return "\n".join(rows) + "\n"


def _summary(images, heights, settings, pairs, overlaps, matches, tracks, inconsistent, kept, refined, sigmas, removed, measurements, stated) -> dict[str, Any]:
    pair_rows = []
    for (i, j), pm in zip(pairs, matches, strict=True):
        both = sum(1 for r in refined if i in r and j in r)
        row = {"images": [images[i].id, images[j].id], "overlap_fraction": round(overlaps[(i, j)], 3)}
        row.update({k: int(v) for k, v in pm.counts.items()})
        row["removed_epipolar"] = removed.get((i, j), 0)
        row["rejected"] = _rejections(pm.counts, removed.get((i, j), 0))
        row["tie_points"] = both
        row["scatter_px"] = round(sigmas[(i, j)], 3) if (i, j) in sigmas else None
        row["sigma_px"] = round(other_sigma(sigmas[(i, j)]), 3) if (i, j) in sigmas else None
        pair_rows.append(row)
    image_rows = []
    for k, im in enumerate(images):
        cells = {cell_of(r[k][0], im.lines, im.columns, settings.grid) for r in refined if k in r}
        own = [stated(r, k) for r in refined if k in r and k != min(r)]
        image_rows.append({"id": im.id, "lines": im.lines, "columns": im.columns, "tie_points": sum(1 for r in refined if k in r),
                           "cells_covered": round(len(cells) / settings.grid**2, 3),
                           "sigma_px": round(float(np.median(own)), 3) if own else None,
                           "reference_measurements": sum(1 for r in refined if k in r and k == min(r))})
    lengths: dict[str, int] = {}
    for r in refined:
        lengths[str(len(r))] = lengths.get(str(len(r)), 0) + 1
    ncc = [v[1] for r in refined for m, v in r.items() if m != min(r)]
    sig = [stated(r, m) for r in refined for m in r if m != min(r)]  # the reference's is a convention
    return {
        "images": image_rows,
        "height_range_m": [float(heights[0]), float(heights[1])],
        "pairs": pair_rows,
        "tracks_linked": len(tracks),
        "tracks_inconsistent": inconsistent,
        "tracks_after_thinning": len(kept),
        "tie_points": len(refined),
        "measurements": len(measurements),
        "images_per_tie_point": dict(sorted(lengths.items())),
        "median_ncc": round(float(np.median(ncc)), 3) if ncc else None,
        "median_sigma_px": round(float(np.median(sig)), 3) if sig else None,
        "settings": asdict(settings),
    }


def _rejections(counts: dict[str, int], removed_epipolar: int) -> dict[str, int]:
    """A pair's features lost at each stage: no candidate in the band, the ratio test, the
    mutual check, RANSAC (including tiles with too few matches for it), the epipolar check."""
    get = counts.get
    return {
        "no_candidate_in_band": get("features", 0) - get("candidates", 0),
        "ratio_test": get("candidates", 0) - get("ratio", 0),
        "mutual_check": get("ratio", 0) - get("mutual", 0),
        "ransac": get("mutual", 0) - get("matched", 0),
        "epipolar_check": removed_epipolar,
    }


def failure_advice(summary: dict[str, Any]) -> str:
    """What to try when matching found no tie point, from the summary's counts."""
    pairs = summary.get("pairs") or []
    features = sum(p.get("features", 0) for p in pairs)
    candidates = sum(p.get("candidates", 0) for p in pairs)
    matched = sum(p.get("matched", 0) for p in pairs)
    lo, hi = summary.get("height_range_m", [0.0, 0.0])
    search = (summary.get("settings") or {}).get("search_px")
    if not features:
        return "no feature was found in the overlap: check that the rasters hold texture (not nodata, not saturated)"
    if candidates < 0.05 * features:
        return (f"few features had a candidate in their band: the orientation is further off than --search-px ({search:g} px) "
                f"or the terrain is outside {lo:.0f} to {hi:.0f} m: widen --search-px or give --heights MIN,MAX")
    if not matched:
        return (f"candidates were found but none passed the ratio, mutual and RANSAC checks: the images may not show the same "
                f"scene (dates, clouds), or the orientation is off by more than --search-px ({search:g} px): try a wider --search-px")
    return ("matches were found but lost in the correlation or the epipolar check: try a lower --min-ncc, or a wider --search-px "
            "when the orientation is poor")
