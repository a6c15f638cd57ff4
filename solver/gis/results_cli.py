"""``pba ground-to-image``, ``pba image-to-ground``, ``pba export-rpc``, ``pba export-geojson``:
results of a finished job for GIS tools (docs/how-to/export-gis.md)."""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from pathlib import Path
from typing import Any, Callable

from solver.geometry.geodesy import GEODETIC_CRS

NO_REPORT = "-"  # in place of the report: the job's own orientation


def _job_report(p: argparse.ArgumentParser, optional: bool = False) -> None:
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.add_argument("report", type=Path, help="its report (pba run -o)" + (
        f"; {NO_REPORT} for none: the job's own orientation (for a job from vendor metadata, pba job --sensor: "
        "the orientation as delivered)" if optional else ""))
    p.add_argument("--image", required=True, help="image id")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ground-to-image", help="image positions of ground points with the adjusted model (CSV)")
    _job_report(p, optional=True)
    p.add_argument("points", type=Path, help="CSV with a header: lon,lat,height (EPSG:4979) or the --crs axes")
    p.add_argument("--crs", default=GEODETIC_CRS, help="CRS of the ground columns (default EPSG:4979: lon,lat,height)")
    p.add_argument("--sigmas", action="store_true", help="add propagated standard deviations sigma_line_px, sigma_column_px")
    p.add_argument("-o", "--output", type=Path, help="CSV to write (default stdout)")
    p.set_defaults(func=announcing(cmd_ground_to_image))

    p = sub.add_parser("image-to-ground", help="ground coordinates of image positions with the adjusted model (CSV)")
    _job_report(p, optional=True)
    p.add_argument("pixels", type=Path, help="CSV with a header: line,column,height (height not needed with --dem)")
    p.add_argument("--crs", default=GEODETIC_CRS, help="CRS of the ground columns written (default EPSG:4979)")
    p.add_argument("--dem", type=Path, help="DEM raster (m; its vertical datum from the file or --dem-vertical) instead of the height column")
    p.add_argument("--dem-vertical", metavar="DATUM", help="the DEM's vertical datum where its file does not state it: ellipsoid, "
                   "egm96 (SRTM), egm2008 (Copernicus DEM) or a vertical CRS (EPSG:code)")
    p.add_argument("--sigmas", action="store_true", help="add propagated standard deviations sigma_east_m, sigma_north_m")
    p.add_argument("-o", "--output", type=Path, help="CSV to write (default stdout)")
    p.set_defaults(func=announcing(cmd_image_to_ground))

    p = sub.add_parser("export-rpc", help="RPC00B fitted to the adjusted model: _RPC.TXT, .RPB or GeoTIFF tags")
    _job_report(p)
    p.add_argument("-o", "--output", type=Path, required=True, help="NAME_RPC.TXT (GDAL's RPC text), NAME.RPB, or NAME.tif with --raster")
    p.add_argument("--raster", type=Path, help="the image's raster: write a GeoTIFF copy with the RPC tags (-o NAME.tif)")
    p.add_argument("--dem", type=Path, help="DEM whose height range the fit grid spans (default: the job's points +- 100 m)")
    p.add_argument("--dem-vertical", metavar="DATUM", help="the DEM's vertical datum where its file does not state it: ellipsoid, "
                   "egm96 (SRTM), egm2008 (Copernicus DEM) or a vertical CRS (EPSG:code)")
    p.add_argument("--per-chip", action="store_true", help="one RPC per CCD chip (NAME_<chip>_RPC.TXT), columns of the chip's sub-image")
    p.add_argument("--fit-report", type=Path, help="JSON with the fit and check-grid residuals")
    p.set_defaults(func=announcing(cmd_export_rpc))

    p = sub.add_parser("ortho", help="orthorectify an image's raster with the adjusted orientation (GeoTIFF)")
    p.add_argument("raster", type=Path, help="the image's raster (raw geometry, as delivered)")
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.add_argument("report", type=Path, help="its report (pba run -o)")
    p.add_argument("--image", required=True, help="image id")
    hg = p.add_mutually_exclusive_group(required=True)
    hg.add_argument("--dem", type=Path, help="DEM raster (m; its vertical datum from the file or --dem-vertical)")
    hg.add_argument("--height", type=float, help="constant ellipsoidal height (m)")
    p.add_argument("--dem-vertical", metavar="DATUM", help="the DEM's vertical datum where its file does not state it: ellipsoid, "
                   "egm96 (SRTM), egm2008 (Copernicus DEM) or a vertical CRS (EPSG:code)")
    p.add_argument("--crs", required=True, help="CRS of the orthoimage, e.g. EPSG:32722")
    p.add_argument("--gsd", type=float, required=True, help="pixel size in CRS units")
    p.add_argument(
        "--method",
        choices=("rigorous", "rpc"),
        default="rigorous",
        help="rigorous (default): the adjusted model on a grid, exact for every image (chips, IOP); "
        "rpc: the fitted RPC through GDAL's warper (as gdalwarp -rpc)",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="orthoimage (GeoTIFF)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=announcing(cmd_ortho))

    p = sub.add_parser("resample", help="the image resampled to an ideal single-array camera, with its RPC (or per-chip sub-images)")
    p.add_argument("raster", type=Path, help="the image's raster (raw geometry, as delivered)")
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.add_argument("report", type=Path, help="its report (pba run -o)")
    p.add_argument("--image", required=True, help="image id")
    p.add_argument("--per-chip", action="store_true", help="instead: each chip's sub-image NAME_<chip>.tif with its NAME_<chip>_RPC.TXT")
    p.add_argument("-o", "--output", type=Path, required=True, help="NAME.tif (its RPC is written beside it as NAME_RPC.TXT)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=announcing(cmd_resample))

    p = sub.add_parser("export-geojson", help="points with discrepancy vectors and image footprints (GeoJSON, CRS84)")
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.add_argument("report", type=Path, help="its report (pba run -o)")
    p.add_argument("-o", "--output", type=Path, help="GeoJSON to write (default stdout)")
    p.set_defaults(func=announcing(cmd_export_geojson))


def announcing(command: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """``command`` saying on standard error when the adjustment's kernels compile (a first run
    after an install: a minute or more), as ``pba run`` does (solver.kernels.cache.compile_notices)."""
    def run(args: argparse.Namespace) -> int:
        from solver.kernels.cache import compile_notices

        with compile_notices(lambda message: print(message, file=sys.stderr, flush=True)):
            return command(args)

    return run


def _fail(message: str) -> int:
    print(message, file=sys.stderr)
    return 2


def _load_model(args: argparse.Namespace):
    from solver.gis.model import ModelMismatch, load_model

    delivered = str(args.report) == NO_REPORT
    if delivered and getattr(args, "sigmas", False):
        raise SystemExit(_fail("--sigmas needs the report of an adjustment (its covariances)"))
    try:
        job = json.loads(args.job.read_text())
        report = None if delivered else json.loads(args.report.read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(_fail(f"cannot read the job or report: {exc}")) from None
    try:
        return load_model(job, report)
    except ModelMismatch as exc:
        raise SystemExit(_fail(f"{args.report}: {exc}")) from None


def _image(model, image_id: str):
    try:
        return model.image(image_id)
    except KeyError as exc:
        raise SystemExit(_fail(str(exc.args[0]))) from None


def read_csv(path: Path) -> list[dict[str, Any]]:
    with open(path, newline="") as f:
        return [{k.strip().lower(): v for k, v in row.items() if k is not None} for row in csv.DictReader(f)]


def write_csv(rows: list[dict[str, Any]], output: Path | None) -> None:
    buf = io.StringIO()
    if rows:
        fields = list(rows[0])
        w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else (repr(v) if isinstance(v, float) else v)) for k, v in r.items()})
    if output:
        output.write_text(buf.getvalue())
    else:
        sys.stdout.write(buf.getvalue())


def cmd_ground_to_image(args: argparse.Namespace) -> int:
    from solver.geometry.geodesy import UnknownCRSError
    from solver.gis.transforms import TableError, ground_to_image_table

    model = _load_model(args)
    image = _image(model, args.image)
    try:
        rows = ground_to_image_table(image, read_csv(args.points), args.crs, args.sigmas)
    except (TableError, UnknownCRSError, OSError) as exc:
        return _fail(f"{args.points}: {exc}")
    write_csv(rows, args.output)
    return 0


def cmd_image_to_ground(args: argparse.Namespace) -> int:
    from solver.geometry.geodesy import UnknownCRSError
    from solver.gis.transforms import TableError, image_to_ground_table

    model = _load_model(args)
    image = _image(model, args.image)
    height_fn = None
    if args.dem:
        from solver.gis.dem import Dem

        try:
            height_fn = Dem(args.dem, args.dem_vertical).height
        except ValueError as exc:  # DemError, VerticalDatumError
            return _fail(str(exc))
    try:
        rows = image_to_ground_table(image, read_csv(args.pixels), args.crs, height_fn, args.sigmas)
    except (TableError, UnknownCRSError, OSError) as exc:
        return _fail(f"{args.pixels}: {exc}")
    write_csv(rows, args.output)
    return 0


def cmd_export_rpc(args: argparse.Namespace) -> int:
    from solver.gis.rpc_export import export_rpcs

    model = _load_model(args)
    image = _image(model, args.image)
    dem_range = None
    if args.dem:
        from solver.gis.dem import Dem

        try:
            dem_range = Dem(args.dem, args.dem_vertical).range_m
        except ValueError as exc:  # DemError, VerticalDatumError
            return _fail(str(exc))
    try:
        written, fits = export_rpcs(model, image, args.output, raster=args.raster, dem_range_m=dem_range, per_chip=args.per_chip)
    except ValueError as exc:
        return _fail(str(exc))
    for fit in fits:
        f, c = fit["fit_residuals"], fit["check_residuals"]
        print(
            f"{fit['image']}{'' if fit['chip'] is None else ' chip ' + fit['chip']}: RPC fit RMS {f['rms_px']:.2g} px (max {f['max_px']:.2g}), "
            f"check grid RMS {c['rms_px']:.2g} px (max {c['max_px']:.2g})",
            file=sys.stderr,
        )
        for w in fit["warnings"]:
            print(f"warning: {w}", file=sys.stderr)
    for path in written:
        print(path)
    if args.fit_report:
        args.fit_report.write_text(json.dumps(fits, indent=1))
    return 0


def cmd_export_geojson(args: argparse.Namespace) -> int:
    from solver.gis.geojson import results_geojson

    model = _load_model(args)
    text = json.dumps(results_geojson(model))
    if args.output:
        args.output.write_text(text)
    else:
        print(text)
    return 0


def _bar(enabled: bool):
    import time

    t0 = time.perf_counter()

    def show(fraction: float, message: str) -> None:
        if not enabled:
            return
        n = int(round(fraction * 30))
        sys.stderr.write(f"\r[{'#' * n}{'-' * (30 - n)}] {fraction * 100:5.1f}% {time.perf_counter() - t0:6.1f}s {message[:40]:<40}")
        if fraction >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def cmd_ortho(args: argparse.Namespace) -> int:
    from solver.geometry.geodesy import UnknownCRSError
    from solver.gis.ortho import orthorectify

    model = _load_model(args)
    image = _image(model, args.image)
    if not args.gsd > 0:
        return _fail("--gsd must be positive")
    rpc = None
    method = args.method
    if method == "rpc":
        from solver.gis.rpc_export import image_rpcs

        dem_range = None
        if args.dem:
            from solver.gis.dem import Dem

            try:
                dem_range = Dem(args.dem, args.dem_vertical).range_m
            except ValueError as exc:  # DemError, VerticalDatumError
                return _fail(str(exc))
        rpc = image_rpcs(model, image, dem_range)[0]
        for w in rpc.fit["warnings"]:
            print(f"warning: {w}", file=sys.stderr)
    try:
        info = orthorectify(image, args.raster, args.output, args.crs, args.gsd, args.height, args.dem, method, _bar(not args.quiet), rpc, args.dem_vertical)
    except (ValueError, UnknownCRSError, OSError) as exc:
        return _fail(str(exc))
    print(f"{args.output}: {info['width']} x {info['height']} pixels of {args.gsd:g} ({args.crs}, {method})")
    return 0


def _rpc_sidecar(tif: Path) -> Path:
    stem = tif.name[: -len(tif.suffix)] if tif.suffix else tif.name
    return tif.with_name(f"{stem}_RPC.TXT")


def cmd_resample(args: argparse.Namespace) -> int:
    from solver.gis.resample import resample_raster, write_chip_rasters
    from solver.gis.rpc_export import height_range, image_rpcs
    from solver.gis.rpc_fit import fit_image_rpc
    from solver.gis.rpc_image import RpcImage
    from solver.gis.rpc_io import write_sidecar

    model = _load_model(args)
    image = _image(model, args.image)
    if isinstance(image, RpcImage):
        return _fail(f"image {image.id!r} is an RPC image: it has no camera to resample from (its refined RPC: pba export-rpc)")
    try:
        if args.per_chip:
            rpcs = image_rpcs(model, image, per_chip=True)
            for k, path in write_chip_rasters(image, args.raster, args.output):
                write_sidecar(rpcs[k], _rpc_sidecar(path))
                c = rpcs[k].fit["check_residuals"]
                print(f"{path} + {_rpc_sidecar(path).name}: RPC check grid RMS {c['rms_px']:.2g} px (max {c['max_px']:.2g})")
            return 0
        ideal = resample_raster(image, args.raster, args.output, _bar(not args.quiet))
    except (ValueError, OSError) as exc:
        return _fail(str(exc))
    rpc = fit_image_rpc(ideal, height_range(model))
    write_sidecar(rpc, _rpc_sidecar(args.output))
    c = rpc.fit["check_residuals"]
    print(f"{args.output} + {_rpc_sidecar(args.output).name}: ideal single-array image; RPC check grid RMS {c['rms_px']:.2g} px (max {c['max_px']:.2g})")
    return 0
