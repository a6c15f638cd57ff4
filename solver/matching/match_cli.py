"""``pba match IMAGE... (--job JOB.json [--report REPORT.json] | images with RPCs) -o ties.csv``:
tie points found in the rasters, guided by the orientation (docs/matching.md)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

GDAL_CACHE_MB = "128"  # GDAL's block cache (default 5% of RAM): windows are read once or twice each


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``match`` to the ``pba`` command line."""
    from solver.matching.features import MatchSettings

    d = MatchSettings()
    p = sub.add_parser(
        "match",
        help="tie points from the images themselves, guided by the orientation (measurement CSV)",
        description="Find tie points in overlapping rasters: SIFT features on a grid of tiles, matched inside the band "
        "the orientation predicts, checked (ratio, mutual, RANSAC, epipolar), refined by correlation, linked into "
        "multi-image points and thinned; writes image,point,line,column,sigma_px.",
    )
    p.add_argument("images", nargs="+", metavar="IMAGE", help="rasters (GDAL), as PATH or ID=PATH (ID: the job's image id)")
    p.add_argument("--job", type=Path, help="job document orienting the images (default: each raster's own RPC)")
    p.add_argument("--report", type=Path, help="the job's report (adjusted orientation; default: the job's initial one)")
    p.add_argument("-o", "--output", type=Path, required=True, help="measurement CSV to write (image,point,line,column,sigma_px)")
    p.add_argument("--summary", type=Path, help="JSON summary to write (pairs, matches per pair, spread, precision)")
    p.add_argument("--heights", help="terrain height range MIN,MAX (ellipsoidal m; default: the DEM's heights under the images +- 50 m "
                   "with --dem, else the job's points +- 100 m, or the RPCs' whole range)")
    p.add_argument("--dem", type=Path, help="DEM of the area (GDAL, georeferenced): narrows the height range to the terrain's, "
                   "for shorter search bands (not with --heights)")
    p.add_argument("--dem-vertical", metavar="DATUM", help="the DEM's vertical datum where its file does not state it: ellipsoid, "
                   "egm96 (SRTM), egm2008 (Copernicus DEM) or a vertical CRS (EPSG:code); see docs/datum.md")
    p.add_argument("--search-px", type=float, default=d.search_px, help=f"half-width of the search band: the orientation's uncertainty in pixels (default {d.search_px:g})")
    p.add_argument("--grid", type=int, default=d.grid, help=f"tiles / thinning cells per image side (default {d.grid})")
    p.add_argument("--per-cell", type=int, default=d.per_cell, help=f"tie points kept per cell of each image (default {d.per_cell})")
    p.add_argument("--min-ncc", type=float, default=d.min_ncc, help=f"lowest accepted correlation peak (default {d.min_ncc:g})")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_match)


def register_gcp(sub: argparse._SubParsersAction) -> None:
    """Add ``match-gcp`` to the ``pba`` command line."""
    from solver.matching.features import MatchSettings

    d = MatchSettings()
    p = sub.add_parser(
        "match-gcp",
        help="control points of an image from an orthophoto (and a DEM), guided by the orientation",
        description="Match an image against a georeferenced orthophoto: a corner per grid cell of the orthophoto, its "
        "ground point (orthophoto CRS, DEM height), predicted in the image by the orientation, found by correlation, "
        "checked for a smooth offset; writes the control points (id,x,y,z: longitude, latitude, ellipsoidal height; "
        "--crs EPSG:4979) and their measurements (image,point,line,column,sigma_px). See docs/matching.md for how "
        "reliable this is.",
    )
    p.add_argument("image", metavar="IMAGE", help="the image's raster, as PATH or ID=PATH (ID: the job's image id)")
    p.add_argument("ortho", type=Path, metavar="ORTHO", help="georeferenced orthophoto (GDAL: GeoTIFF, JPEG 2000, ...)")
    p.add_argument("--dem", type=Path, help="DEM under the orthophoto (GDAL, georeferenced): the control points' heights")
    p.add_argument("--dem-vertical", metavar="DATUM", help="the DEM's vertical datum where its file does not state it: ellipsoid, "
                   "egm96 (SRTM), egm2008 (Copernicus DEM) or a vertical CRS (EPSG:code); see docs/datum.md")
    p.add_argument("--dem-sigma", type=float, metavar="METRES", help="the DEM's vertical accuracy (one sigma): the control points "
                   "get survey sigmas (the orthophoto's pixel horizontally, the DEM height's sigma vertically)")
    p.add_argument("--height", type=float, help="the terrain's ellipsoidal height (m) where there is no DEM")
    p.add_argument("--job", type=Path, help="job document orienting the image (default: the raster's own RPC)")
    p.add_argument("--report", type=Path, help="the job's report (adjusted orientation; default: the job's initial one)")
    p.add_argument("-o", "--output", type=Path, required=True, help="control points table to write (id,x,y,z,role; CRS EPSG:4979)")
    p.add_argument("--measurements", type=Path, required=True, help="measurement CSV to write (image,point,line,column,sigma_px)")
    p.add_argument("--summary", type=Path, help="JSON summary to write (candidates, matches, removed, sigma)")
    p.add_argument("--search-px", type=float, default=d.search_px, help=f"half-width of the search: the orientation's uncertainty in orthophoto pixels (default {d.search_px:g})")
    p.add_argument("--grid", type=int, default=d.grid, help=f"cells per side of the orthophoto's part under the image: one candidate each (default {d.grid})")
    p.add_argument("--min-ncc", type=float, default=d.min_ncc, help=f"lowest accepted correlation peak (default {d.min_ncc:g})")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_match_gcp, per_cell=1, images=None, heights=None)


def cmd_match_gcp(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from solver.errors import JobError
    from solver.gis.model import ModelMismatch
    from solver.matching.gcp import GCP_CRS, GcpError, control_points_csv, match_gcps
    from solver.matching.orientation import OrientationError
    from solver.matching.pipeline import measurements_csv
    from solver.matching.raster import RasterError

    os.environ.setdefault("GDAL_CACHEMAX", GDAL_CACHE_MB)
    args.images = [args.image]
    images = []
    try:
        settings = settings_from_args(args)
        if args.height is not None and not math.isfinite(args.height):
            raise ValueError("--height must be a number of metres")
        if args.dem_sigma is not None and not (math.isfinite(args.dem_sigma) and args.dem_sigma > 0):
            raise ValueError("--dem-sigma must be a positive number of metres")
        images, _heights = load_images(args)
        result = match_gcps(images[0], args.ortho, args.dem, args.height, settings, _bar(not args.quiet),
                            dem_vertical=args.dem_vertical, dem_sigma_m=args.dem_sigma)
    except (RasterError, OrientationError, GcpError, ModelMismatch, ValueError) as exc:
        return _fail(str(exc), "match-gcp")
    except ValidationError as exc:
        return _fail(f"{args.job}: invalid job document: " + "; ".join(f"{'/'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors()[:5]), "match-gcp")
    except JobError as exc:
        return _fail(f"{args.job}: " + "; ".join(f"[{p.code}] {p.message}" for p in exc.problems[:5]), "match-gcp")
    finally:
        for im in images:
            im.raster.close()
    if not result.points:
        return _fail("no control point survived the checks (see --summary)", "match-gcp")
    args.output.write_text(control_points_csv(result.points))
    args.measurements.write_text(measurements_csv(result.measurements))
    if args.summary:
        args.summary.write_text(json.dumps(result.summary, indent=1))
    s = result.summary
    print(f"{args.output}: {s['control_points']} control points ({GCP_CRS}) of {s['candidates']} candidates, "
          f"{s['removed_inconsistent']} removed as inconsistent; sigma line {s['sigma_px']['line']} px, column {s['sigma_px']['column']} px; "
          f"measurements in {args.measurements}")
    return 0


def _write_summary(path: Path | None, summary: dict | None) -> str:
    """Write ``summary`` (JSON) to ``path`` when both are given; the words a message adds."""
    if path is None or summary is None:
        return " (--summary FILE writes the counts per pair)" if summary is not None else ""
    path.write_text(json.dumps(summary, indent=1))
    return f" (counts per pair in {path})"


def _fail(message: str, command: str = "match") -> int:
    print(f"pba {command}: {message}", file=sys.stderr)
    return 2


def _bar(enabled: bool):
    t0 = time.perf_counter()
    shown = [-1.0]

    def show(fraction: float, message: str) -> None:
        if not enabled or (fraction - shown[0] < 0.002 and fraction < 1.0):
            return
        shown[0] = fraction
        n = int(round(fraction * 30))
        sys.stderr.write(f"\r[{'#' * n}{'-' * (30 - n)}] {fraction * 100:5.1f}% {time.perf_counter() - t0:6.1f}s {message[:30]:<30}")
        if fraction >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def settings_from_args(args: argparse.Namespace):
    from solver.matching.features import MatchSettings

    if args.search_px <= 0 or args.grid < 1 or args.per_cell < 1 or not (0 < args.min_ncc < 1):
        raise ValueError("--search-px must be positive, --grid and --per-cell at least 1, --min-ncc between 0 and 1")
    if args.grid > 200:
        raise ValueError("--grid is at most 200")
    return MatchSettings(grid=args.grid, per_cell=args.per_cell, search_px=args.search_px, min_ncc=args.min_ncc)


def load_images(args: argparse.Namespace):
    """(images, height range) from the job (and report) or the rasters' RPCs; raises the
    matching's errors with located messages."""
    from solver.matching.orientation import OrientationError, height_range_arg, images_from_job, images_from_rpcs

    if args.report and not args.job:
        raise OrientationError("--report needs --job")
    if args.job:
        try:
            job = json.loads(args.job.read_text())
            report = json.loads(args.report.read_text()) if args.report else None
        except (OSError, ValueError) as exc:
            raise OrientationError(f"cannot read the job or report: {exc}") from None
        images, heights = images_from_job(job, report, args.images)
    else:
        images, heights = images_from_rpcs(args.images)
    if args.heights:
        heights = height_range_arg(args.heights)
    return images, heights


def _validation_errors(exc: Exception) -> list[dict] | None:
    """pydantic's errors of ``exc`` when it is a ValidationError (an invalid job document), else
    None; pydantic is only looked for where a job was read (imported by then)."""
    pydantic = sys.modules.get("pydantic")
    return exc.errors() if pydantic is not None and isinstance(exc, pydantic.ValidationError) else None


def cmd_match(args: argparse.Namespace) -> int:
    from solver.errors import JobError
    from solver.matching.orientation import OrientationError
    from solver.matching.pipeline import MatchError, failure_advice, match_images, measurements_csv
    from solver.matching.raster import RasterError

    os.environ.setdefault("GDAL_CACHEMAX", GDAL_CACHE_MB)  # before GDAL's first read allocates its cache
    images = []
    try:
        settings = settings_from_args(args)
        images, heights = load_images(args)
        terrain = None
        if args.dem is not None:
            from solver.matching.heights import dem_heights

            if args.heights:
                raise ValueError("give --heights or --dem, not both")
            heights, terrain = dem_heights(images, heights, args.dem, args.dem_vertical)
        result = match_images(images, heights, settings, _bar(not args.quiet), terrain=terrain)
    except MatchError as exc:
        return _fail(str(exc) + _write_summary(args.summary, exc.summary))
    except (RasterError, OrientationError, ValueError) as exc:  # the model's ModelMismatch and pydantic's ValidationError are ValueErrors
        errors = _validation_errors(exc)
        if errors is not None:
            return _fail(f"{args.job}: invalid job document: " + "; ".join(f"{'/'.join(map(str, e['loc']))}: {e['msg']}" for e in errors[:5]))
        return _fail(str(exc))
    except JobError as exc:
        return _fail(f"{args.job}: " + "; ".join(f"[{p.code}] {p.message}" for p in exc.problems[:5]))
    finally:
        for im in images:
            im.raster.close()
    if not result.measurements:
        return _fail("no tie point survived the checks: " + failure_advice(result.summary) + _write_summary(args.summary, result.summary))
    args.output.write_text(measurements_csv(result.measurements))
    _write_summary(args.summary, result.summary)
    s = result.summary
    print(f"{args.output}: {s['tie_points']} tie points, {s['measurements']} measurements in {len(s['images'])} images "
          f"({len(s['pairs'])} overlapping pairs)")
    for im in s["images"]:
        print(f"  {im['id']}: {im['tie_points']} tie points, {round(100 * im['cells_covered'])}% of its cells, "
              + (f"sigma {im['sigma_px']} px" if im["sigma_px"] is not None else "the reference of its tie points"))
    for row in s["pairs"]:
        print(f"  {row['images'][0]}-{row['images'][1]}: {row.get('matched', 0)} matches, {row['removed_epipolar']} removed by the epipolar check, "
              f"{row['tie_points']} tie points, " + (f"sigma {row['sigma_px']} px" if row["sigma_px"] is not None else "sigma not estimated"))
    return 0
