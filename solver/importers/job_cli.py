"""``pba job``: compose a job document from survey, measurement, ephemeris and attitude files,
validate it and say what it holds; ``pba job-sources``: the inverse (a job's source files).

Example::

    pba job --camera prism-nadir --image N=N_points.csv --gcps survey.csv --crs EPSG:31982 \\
        --model K2 -o job.json
    pba job --rpc N=N.tif --rpc-model RPC-SHIFT --image N=N_points.csv --gcps survey.csv -o job.json
    pba job --sensor L=L.XML --sensor R=R.XML --image L=L_points.csv --image R=R_points.csv \\
        --gcps survey.csv -o job.json

Flags taking ``ID=VALUE`` are per image (``--camera N=prism-nadir``); ``--camera NAME`` alone
is the default of every image. A measurement file's type follows its extension: ``.csv``
(our pixel convention), ``.points`` (QGIS Georeferencer), ``.gcp`` (ASP). Problems in files
are printed as ``file, line L, column C: message``; the exit status is 0 for a valid job, 1
for a job the solver's checks refuse (the document is still written), 2 when no job could be
composed.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from solver.importers.errors import SourceError, fail

if TYPE_CHECKING:  # imported where a job is composed: not for every command line (pydantic, the readers)
    from solver.importers.compose import ComposeRequest, ImageSources, SourceFile


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("job", help="compose a job document from survey, measurement and ephemeris files")
    p.add_argument("--image", action="append", default=[], metavar="[ID=]FILE",
                   help="measurements of image ID (.csv, .points, .gcp); repeat for more files or images. Without "
                   "ID=: a CSV whose image column names each row's image (the tie points of pba match -o)")
    p.add_argument("--camera", action="append", default=[], metavar="[ID=]NAME",
                   help="camera by name: a preset (prism-backward, prism-nadir, prism-forward, cbers-ccd) "
                   "or a camera of --camera-file; ID= for one image")
    p.add_argument("--camera-file", action="append", default=[], type=Path, metavar="FILE",
                   help="JSON camera definitions (a camera, a list, or {\"cameras\": [...]})")
    p.add_argument("--gcps", action="append", default=[], type=Path, metavar="FILE", help="control points table")
    p.add_argument("--checks", action="append", default=[], type=Path, metavar="FILE", help="check points table")
    p.add_argument("--points", action="append", default=[], type=Path, metavar="FILE",
                   help="points table with a role column (gcp, check, tie)")
    p.add_argument("--crs", help="CRS of the point tables (EPSG code or PROJ string; default EPSG:4326)")
    p.add_argument("--asp-gcp", action="append", default=[], type=Path, metavar="FILE",
                   help="ASP GCP file naming its images (image ids: the file names without extension)")
    p.add_argument("--ephemeris", action="append", default=[], metavar="ID=FILE", help="state vectors of image ID")
    p.add_argument("--attitude", action="append", default=[], metavar="ID=FILE", help="attitude samples of image ID")
    p.add_argument("--first-line-time", action="append", default=[], metavar="ID=SECONDS",
                   help="time of image ID's first line (s, in the time scale of its ephemeris) where no header state gives it")
    p.add_argument("--attitude-base", action="append", default=[], metavar="ID=FILE",
                   help="the delivered attitude of image ID (an attitude table): the base the orbit-attitude and pass models correct")
    p.add_argument("--state", action="append", default=[], metavar="ID=FILE",
                   help="header state of image ID: one row, the state at the first line and its time")
    p.add_argument("--sensor", action="append", default=[], metavar="ID=FILE",
                   help="vendor sensor metadata of image ID (Maxar XML, SPOT 5 DIMAP): its camera, ephemeris, "
                   "attitude, line times, model and weights (pba import-sensor)")
    p.add_argument("--rpc", action="append", default=[], metavar="ID=FILE",
                   help="image ID is an RPC image: its raster (RPC tags or a sidecar beside it), NAME_RPC.TXT, "
                   "NAME.RPB or DIMAP RPC XML, read by GDAL (no camera or time files for it)")
    p.add_argument("--rpc-model", action="append", default=[], metavar="[ID=]NAME",
                   help="bias model of the RPC images (RPC-SHIFT, RPC-DRIFT, RPC-AFFINE; default RPC-DRIFT); ID= for one image")
    p.add_argument("--bias-prior", type=float, metavar="PX",
                   help="a 0 +- PX prior on every RPC image's bias terms (offsets in px; drift terms PX over the "
                   "image's extent): the RPCs' own ground reference defines the datum")
    p.add_argument("--dem", metavar="DEM", help="a DEM raster (GeoTIFF, JPEG 2000; an SRTM .hgt tile: gdal_translate it to GeoTIFF first): its heights of the tie points become "
                   "observations, re-read as the points move (job.dem; docs/datum.md)")
    p.add_argument("--dem-sigma", type=float, default=5.0, metavar="METRES",
                   help="the DEM's vertical accuracy, one sigma (default 5; SRTM about 6, Copernicus DEM about 3)")
    p.add_argument("--dem-vertical", metavar="DATUM", help="the DEM's vertical datum where its file does not state it: ellipsoid, "
                   "egm96 (SRTM), egm2008 (Copernicus DEM) or a vertical CRS (EPSG:code)")
    p.add_argument("--time-scale", help="time scale of time files that do not state one (GPS, UTC, ...)")
    p.add_argument("--columns", action="append", default=[], metavar="FILE:NAME=COLUMN[,...]",
                   help="map a file's column names onto the format's (e.g. survey.csv:E=x,N=y,H=z)")
    p.add_argument("--model", default="K2",
                   help="platform model of the images with a camera; several comma-separated: a model comparison")
    p.add_argument("--options", help="solver options as JSON (object) or a JSON file")
    p.add_argument("--name", default="job", help="job name")
    p.add_argument("--sigma-px", type=float, default=0.5, help="measurement sigma where a file gives none (px)")
    p.add_argument("--match-tolerance", type=float, default=1.0,
                   help=".points rows are matched to survey points within this distance (m)")
    p.add_argument("--map-crs", help="CRS of .points files without a #CRS: line")
    p.add_argument("--match", action="append", default=[], metavar="ID=RASTER",
                   help="add tie points matched in these rasters (pba match, guided by the composed job's initial "
                   "orientation; at least two images); see docs/matching.md")
    p.add_argument("--match-summary", type=Path, metavar="FILE", help="with --match: the matching's summary (JSON)")
    p.add_argument("--match-heights", metavar="MIN,MAX", help="with --match: the terrain's ellipsoidal height range in metres "
                   "(default: the job's points +- 100 m, or the RPCs' range)")
    p.add_argument("--control-from", type=Path, metavar="ORTHO",
                   help="a georeferenced orthophoto: control points matched in the --control-image rasters (pba match-gcp, "
                   "guided by the composed job's initial orientation; heights from --dem with its --dem-vertical, survey "
                   "sigmas from --dem-sigma and the orthophoto's pixel) are added to the job; see docs/matching.md")
    p.add_argument("--control-image", action="append", default=[], metavar="ID=RASTER",
                   help="with --control-from: the raster of image ID matched against the orthophoto; repeat for more images")
    p.add_argument("--control-height", type=float, metavar="METRES",
                   help="with --control-from and no --dem: the terrain's ellipsoidal height (the points then get no survey sigma)")
    p.add_argument("-o", "--output", type=Path, help="job document (JSON); default stdout")
    p.set_defaults(func=cmd_job)

    p = sub.add_parser("job-sources", help="write a job's measurements, survey and tables back as source files")
    p.add_argument("job", type=Path, help="job document (JSON)")
    p.add_argument("-o", "--output", type=Path, required=True, help="directory")
    p.add_argument("--format", action="append", default=[], metavar="ID=FORMAT",
                   help="measurement format of image ID: csv (default), qgis, asp")
    p.set_defaults(func=cmd_job_sources)


def _pairs(values: list[str], flag: str) -> list[tuple[str, str]]:
    out = []
    for v in values:
        if "=" not in v:
            raise fail(flag, 0, "", f"{v!r}: expected ID=VALUE", "bad_argument")
        k, val = v.split("=", 1)
        out.append((k, val))
    return out


def _file(path: Path | str, columns: dict[str, dict[str, str]]) -> SourceFile:
    from solver.importers.compose import SourceFile

    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise fail(str(path), 0, "", f"cannot read: {exc.strerror}", "unreadable_file") from None
    return SourceFile(str(path), data, columns.get(str(path), {}))


def _column_maps(values: list[str]) -> dict[str, dict[str, str]]:
    out: dict[str, dict[str, str]] = {}
    for v in values:
        path, _, spec = v.rpartition(":")
        if not path or not spec:
            raise fail("--columns", 0, "", f"{v!r}: expected FILE:NAME=COLUMN[,...]", "bad_argument")
        out[path] = dict(pair.split("=", 1) for pair in spec.split(",") if "=" in pair)
    return out


def request_from_args(args: argparse.Namespace) -> ComposeRequest:
    """The composition the flags describe (files read here)."""
    from solver.importers.compose import ComposeRequest, ImageSources, SourceFile

    columns = _column_maps(args.columns)
    images: dict[str, ImageSources] = {}

    def image(iid: str) -> ImageSources:
        return images.setdefault(iid, ImageSources(iid))

    named: list[SourceFile] = []  # CSVs whose rows name their images
    for v in args.image:
        if "=" in v:
            iid, path = v.split("=", 1)
            image(iid).measurements.append(_file(path, columns))
        else:
            named.append(_file(v, columns))

    def per_image(values: list[str], attr: str, default: str | None) -> str | None:
        """``[ID=]NAME`` flags: ID=NAME sets ``attr`` of that image, NAME alone the default."""
        for v in values:
            if "=" in v:
                iid, name = v.split("=", 1)
                setattr(image(iid), attr, name)
            else:
                default = v
        return default

    default_camera = per_image(args.camera, "camera", None)
    for flag, attr in (("--ephemeris", "ephemeris"), ("--attitude", "attitude"), ("--attitude-base", "attitude_base"), ("--state", "state")):
        for iid, path in _pairs(getattr(args, attr), flag):
            setattr(image(iid), attr, _file(path, columns))
    for iid, value in _pairs(args.first_line_time, "--first-line-time"):
        try:
            image(iid).first_line_time_s = float(value)
        except ValueError:
            raise fail("--first-line-time", 0, "", f"{iid}={value!r}: the first line's time in seconds is expected", "bad_argument") from None
    for iid, path in _pairs(args.rpc, "--rpc"):  # read by GDAL from its place (sidecars beside a raster)
        image(iid).rpc = SourceFile(path, b"", path=path)
    for iid, path in _pairs(args.sensor, "--sensor"):  # vendor metadata, read where it is
        image(iid).sensor = SourceFile(path, b"", path=path)
    rpc_model = per_image(args.rpc_model, "rpc_model", "RPC-DRIFT")
    options: dict[str, Any] = {}
    if args.options:
        text = Path(args.options).read_text() if Path(args.options).is_file() else args.options
        try:
            options = json.loads(text)
        except ValueError as exc:
            raise fail("--options", 0, "", f"not JSON: {exc}", "bad_argument") from None
        if not isinstance(options, dict):
            raise fail("--options", 0, "", "a JSON object is expected", "bad_argument")
    return ComposeRequest(
        images=list(images.values()),
        gcps=[_file(p, columns) for p in args.gcps],
        checks=[_file(p, columns) for p in args.checks],
        points=[_file(p, columns) for p in args.points],
        asp_gcp=[_file(p, columns) for p in args.asp_gcp],
        measurements=named,
        camera_files=[_file(p, columns) for p in args.camera_file],
        camera=default_camera,
        crs=args.crs,
        models=[m.strip() for m in args.model.split(",") if m.strip()],
        rpc_model=rpc_model,
        bias_prior_px=args.bias_prior,
        dem=SourceFile(args.dem, b"", path=args.dem) if args.dem else None,
        dem_sigma_m=args.dem_sigma,
        dem_vertical=args.dem_vertical,
        options=options,
        name=args.name,
        time_scale=args.time_scale,
        sigma_px=args.sigma_px,
        match_tolerance_m=args.match_tolerance,
        map_crs=args.map_crs,
    )


def cmd_job(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from solver.api import validate
    from solver.importers.compose import compose_job, format_summary, summarize
    from solver.schema.job import load_job

    try:
        composed = compose_job(request_from_args(args))
    except SourceError as exc:
        for p in exc.source_problems:
            print(p, file=sys.stderr)
        return 2
    for note in composed.notes:
        print(f"note: {note}", file=sys.stderr)
    if args.match:
        try:
            summary = add_matched_ties(composed.job, args.match, heights=args.match_heights)
        except ValueError as exc:
            print(f"--match: {exc}", file=sys.stderr)
            return 2
        if args.match_summary:
            args.match_summary.write_text(json.dumps(summary, indent=1))
        for row in summary["pairs"]:
            print(f"matched {row['images'][0]}-{row['images'][1]}: {row.get('matched', 0)} matches, "
                  f"{row['removed_epipolar']} removed by the epipolar check, {row['tie_points']} tie points", file=sys.stderr)
    if args.control_from or args.control_image:
        try:
            summaries = add_reference_control(composed.job, args.control_from, args.control_image, args.dem, args.dem_vertical,
                                              args.dem_sigma, args.control_height)
        except ValueError as exc:
            print(f"--control-from: {exc}", file=sys.stderr)
            return 2
        for row in summaries:
            print(f"control from the orthophoto in {row['image']}: {row['control_points']} control points of {row['candidates']} candidates, "
                  f"{row['removed_inconsistent']} removed as inconsistent", file=sys.stderr)
    text = json.dumps(composed.job, indent=1) + "\n"
    if args.output:
        args.output.write_text(text)
    else:
        sys.stdout.write(text)
    try:
        job = load_job(composed.job)
    except ValidationError as exc:
        for err in exc.errors():
            print("invalid: /" + "/".join(str(x) for x in err["loc"]) + f": {err['msg']}", file=sys.stderr)
        return 1
    for line in format_summary(summarize(composed.job)):
        print(line, file=sys.stderr)
    result = validate(job)
    for p in result.get("problems", []):
        print("problem: /" + "/".join(str(x) for x in p.get("location", [])) + f": {p['message']}", file=sys.stderr)
    if result.get("valid"):
        print(f"valid: {result.get('n_observations')} observations, {result.get('n_unknowns')} unknowns, "
              f"{result.get('dof')} degrees of freedom", file=sys.stderr)
        return 0
    return 1


def add_matched_ties(job: dict[str, Any], rasters: list[str], settings=None, heights: str | None = None) -> dict[str, Any]:
    """Tie points matched in ``rasters`` (``ID=PATH``) added to the composed ``job`` (in place),
    oriented by the job's initial orientation; the matching's summary. Raises ValueError
    (the matching's located errors) when matching cannot run. ``settings``: a
    :class:`solver.matching.features.MatchSettings` (default: the defaults of ``pba match``);
    ``heights``: ``MIN,MAX`` ellipsoidal metres (default: the job's or the RPCs' range)."""
    from solver.errors import JobError
    from solver.matching.features import MatchSettings
    from solver.matching.orientation import height_range_arg, images_from_job
    from solver.matching.pipeline import match_images

    images = []
    try:
        images, heights_m = images_from_job(job, None, rasters)
        if heights:
            heights_m = height_range_arg(heights, "--match-heights")
        result = match_images(images, heights_m, settings or MatchSettings())
    except JobError as exc:
        raise ValueError("the composed job cannot orient the images: " + "; ".join(p.message for p in exc.problems[:3])) from None
    finally:
        for im in images:
            im.raster.close()
    taken = {p["id"] for p in job.get("points", [])}
    prefix = "M"
    while any(m["point"].replace("M", prefix, 1) in taken for m in result.measurements):
        prefix += "M"
    for m in result.measurements:
        m["point"] = m["point"].replace("M", prefix, 1)
    job.setdefault("points", []).extend({"id": pid, "role": "tie"} for pid in dict.fromkeys(m["point"] for m in result.measurements))
    job.setdefault("observations", []).extend(result.measurements)
    return result.summary


def add_reference_control(job: dict[str, Any], ortho: Path | None, rasters: list[str], dem: str | None, dem_vertical: str | None,
                          dem_sigma_m: float | None, height_m: float | None) -> list[dict[str, Any]]:
    """Control points matched in each of ``rasters`` (``ID=PATH``) against the orthophoto
    ``ortho`` (:func:`solver.matching.gcp.match_gcps`), oriented by the composed ``job``'s
    initial orientation, added to ``job`` in place: role gcp, longitude, latitude and
    ellipsoidal height (EPSG:4979, each point's ``crs``), heights from ``dem`` (with survey
    sigmas from ``dem_sigma_m`` and the orthophoto's pixel) or ``height_m`` (no sigma: held),
    ids ``<image>.G<n>``. Returns each image's matching summary; raises ValueError with the
    reason when the control cannot be matched."""
    from solver.errors import JobError
    from solver.geometry.dem import DemError
    from solver.matching.features import MatchSettings
    from solver.matching.gcp import GCP_CRS, GcpError, match_gcps
    from solver.matching.orientation import OrientationError, images_from_job
    from solver.matching.raster import RasterError

    if ortho is None or not rasters:
        raise ValueError("give the orthophoto (--control-from ORTHO) and at least one --control-image ID=RASTER")
    if dem is None and height_m is None:
        raise ValueError("give the terrain: --dem DEM or --control-height METRES (ellipsoidal)")
    taken = {p["id"] for p in job.get("points", [])}
    summaries = []
    for raster in rasters:
        images = []
        try:
            images, _heights = images_from_job(job, None, [raster])
            result = match_gcps(images[0], ortho, Path(dem) if dem else None, height_m, MatchSettings(),
                                dem_vertical=dem_vertical, dem_sigma_m=dem_sigma_m if dem else None)
        except JobError as exc:
            raise ValueError("the composed job cannot orient the images: " + "; ".join(p.message for p in exc.problems[:3])) from None
        except (GcpError, OrientationError, RasterError, DemError) as exc:
            raise ValueError(f"{raster}: {exc}") from None
        finally:
            for im in images:
                im.raster.close()
        image_id = images[0].id
        ids = {p["id"]: f"{image_id}.{p['id']}" for p in result.points}
        clash = sorted(set(ids.values()) & taken)
        if clash:
            raise ValueError(f"the job already has points named {', '.join(clash[:3])}")
        taken |= set(ids.values())
        for p in result.points:
            job.setdefault("points", []).append({**p, "id": ids[p["id"]], "crs": GCP_CRS})
        for m in result.measurements:
            job.setdefault("observations", []).append({**m, "point": ids[m["point"]]})
        summaries.append(result.summary)
    return summaries


def cmd_job_sources(args: argparse.Namespace) -> int:
    from solver.importers.export import FORMATS, write_sources

    job = json.loads(args.job.read_text())
    formats = {}
    for v in args.format:
        iid, _, fmt = v.partition("=")
        if fmt not in FORMATS:
            print(f"--format {v}: one of {', '.join(FORMATS)}", file=sys.stderr)
            return 2
        formats[iid] = fmt
    call = write_sources(job, args.output, formats)
    print("pba job " + shlex.join(call) + " -o job.json", file=sys.stderr)
    return 0
