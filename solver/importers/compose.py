"""Compose a job document from the files a photogrammetrist has, and say what is in it.

The sources (one request, :class:`ComposeRequest`): survey tables of control, check and tie
points (:mod:`~solver.importers.points_csv`) in one CRS; per image, measurement files
(CSV, QGIS ``.points`` or ASP ``.gcp``, chosen by the file name's extension, see
:data:`MEASUREMENT_KINDS`), an ephemeris, an attitude table and a header state
(:mod:`~solver.importers.ephemeris_csv`, :mod:`~solver.importers.attitude_csv`), and its
camera by name: a camera of a JSON camera file, else a preset
(:mod:`~solver.importers.presets`), else whatever the caller's ``camera_lookup`` finds (the
service's camera library). ASP GCP files not tied to one image may name several images.

Composition rules:

- every point measured in an image but in no survey becomes a tie point (no coordinates);
- an ASP GCP file's points are control points unless a survey already has the id (then the
  survey's coordinates, role and sigmas stand);
- the job's ``crs`` is the survey's CRS; points from other CRSs (ASP: WGS 84) carry their own;
- all the time files of one image must state one time scale (``time_scale_mismatch``).

:func:`summarize` reports counts per image and role, points seen by one image only and
measurements outside their image. Every file problem is a
:class:`~solver.importers.errors.SourceError` naming file, line and column.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import PurePath
from typing import Any

import numpy as np

from solver.geometry.geodesy import UnknownCRSError, parse_crs
from solver.importers.asp_gcp import read_asp_gcp
from solver.importers.attitude_csv import read_attitude
from solver.importers.ephemeris_csv import read_ephemeris, read_state
from solver.importers.errors import SourceError, SourceProblem, fail
from solver.importers.measurements_csv import read_measurements
from solver.importers.points_csv import read_points
from solver.importers.presets import preset_camera, preset_names
from solver.importers.qgis_points import read_qgis_points

MEASUREMENT_KINDS = {".csv": "csv", ".txt": "csv", ".tsv": "csv", ".points": "qgis", ".gcp": "asp"}
DEFAULT_CRS = "EPSG:4326"
ROLES = ("gcp", "check", "tie")


@dataclass
class SourceFile:
    """One uploaded or named file: ``name`` as the user knows it (errors cite it), its bytes,
    and a map of its column names onto the format's (for unrecognised headers)."""

    name: str
    data: bytes | str
    columns: dict[str, str] = field(default_factory=dict)
    # a file on the caller's own disk (``pba job``): GDAL then also finds an RPC sidecar beside a
    # raster; never set for uploads (their names are not paths of the server's)
    path: str | None = None

    @property
    def kind(self) -> str | None:
        return MEASUREMENT_KINDS.get(PurePath(self.name).suffix.lower())


@dataclass
class ImageSources:
    """What is known of one image: its id, measurement files, camera name and time files; or,
    for an RPC image, its RPC file (a raster or a sidecar GDAL reads) instead of camera and
    times, and optionally its bias model (default ``ComposeRequest.rpc_model``)."""

    id: str
    measurements: list[SourceFile] = field(default_factory=list)
    camera: str | None = None
    ephemeris: SourceFile | None = None
    attitude: SourceFile | None = None
    attitude_base: SourceFile | None = None  # the delivered attitude the models correct (images[].attitude_base)
    state: SourceFile | None = None
    first_line_time_s: float | None = None
    rpc: SourceFile | None = None
    rpc_model: str | None = None
    sensor: SourceFile | None = None  # vendor metadata: camera, ephemeris, attitude, times, model


@dataclass
class ComposeRequest:
    """A whole composition (see the module docstring). ``models``: one name, or several for
    a model comparison (``options.models``; the images take the first)."""

    images: list[ImageSources]
    gcps: list[SourceFile] = field(default_factory=list)
    checks: list[SourceFile] = field(default_factory=list)
    points: list[SourceFile] = field(default_factory=list)  # with a role column
    asp_gcp: list[SourceFile] = field(default_factory=list)  # files naming their images
    measurements: list[SourceFile] = field(default_factory=list)  # CSVs whose rows name their images (pba match -o)
    camera_files: list[SourceFile] = field(default_factory=list)
    camera: str | None = None  # default camera of images without their own
    crs: str | None = None
    models: list[str] = field(default_factory=lambda: ["K2"])  # of the images with a camera
    rpc_model: str = "RPC-DRIFT"  # bias model of the RPC images without their own
    bias_prior_px: float | None = None  # a 0 +- this prior on every RPC image's bias terms (rpc_bias_priors)
    dem: SourceFile | None = None  # a DEM raster: heights of the tie points as observations (job.dem)
    dem_sigma_m: float = 5.0  # the DEM's vertical accuracy, one sigma
    dem_vertical: str | None = None  # the DEM's vertical datum where its file does not state it
    options: dict[str, Any] = field(default_factory=dict)
    name: str = "job"
    time_scale: str | None = None
    sigma_px: float = 0.5
    match_tolerance_m: float = 1.0
    map_crs: str | None = None  # of .points files without a #CRS line


CameraLookup = Callable[[str], "dict[str, Any] | None"]


def preset_lookup(name: str) -> dict[str, Any] | None:
    """A camera definition (without id) from the presets."""
    cam = preset_camera(name)
    if cam is not None:
        cam.pop("id")
    return cam


@dataclass
class Composed:
    """The job document (a dict, not yet schema-validated) and the notes of the import."""

    job: dict[str, Any]
    notes: list[str]


def compose_job(req: ComposeRequest, camera_lookup: CameraLookup = preset_lookup) -> Composed:
    """The job document of ``req`` (SourceError with every located problem found)."""
    problems: list[SourceProblem] = []
    notes: list[str] = []
    crs = req.crs or DEFAULT_CRS
    try:
        parse_crs(crs)
    except UnknownCRSError as exc:
        raise fail("crs", 0, "", str(exc), "unknown_crs") from None
    if req.bias_prior_px is not None and not 0.0 < req.bias_prior_px < float("inf"):
        raise fail("bias_prior_px", 0, "", f"{req.bias_prior_px}: a positive number of pixels is expected", "bad_argument")
    if not req.images:
        raise fail("images", 0, "", "no image: give at least one (--image ID=measurements file)", "no_image")

    points: dict[str, dict[str, Any]] = {}
    origin: dict[str, str] = {}
    for files, role in ((req.gcps, "gcp"), (req.checks, "check"), (req.points, None)):
        for f in files:
            try:
                for p in read_points(f.data, f.name, role, f.columns):
                    if p["id"] in points:
                        problems.append(SourceProblem(f.name, 0, "id", f"point {p['id']!r} is also in {origin[p['id']]}"))
                        continue
                    points[p["id"]] = p
                    origin[p["id"]] = f.name
            except SourceError as exc:
                problems += exc.source_problems
    surveyed = list(points.values())

    sensors = _sensor_fragment(req, problems)
    observations: list[dict[str, Any]] = []
    images: list[dict[str, Any]] = []
    image_ids = [im.id for im in req.images]
    for f in req.asp_gcp:
        observations += _asp(f, None, points, origin, crs, notes, problems)
    for f in req.measurements:
        observations += _named_measurements(f, image_ids, req.sigma_px, problems)
    for im in req.images:
        for f in im.measurements:
            try:
                observations += _measurements(f, im.id, req, surveyed, crs, points, origin, notes, problems)
            except SourceError as exc:
                problems += exc.source_problems
        if im.sensor is not None:
            if im.id in sensors["images"]:
                images.append(sensors["images"][im.id])
            continue
        try:
            images.append(_image(im, req))
        except SourceError as exc:
            problems += exc.source_problems
    for o in observations:
        if o["image"] not in image_ids:
            problems.append(
                SourceProblem("asp_gcp", 0, "image", f"image {o['image']!r} is not one of the images given ({', '.join(image_ids)})")
            )
            break
    cameras = _cameras(req, camera_lookup, problems) + sensors["cameras"]
    if problems:
        raise SourceError(problems)

    ties = 0
    for o in observations:
        if o["point"] not in points:
            points[o["point"]] = {"id": o["point"], "role": "tie"}
            ties += 1
    if ties:
        notes.append(f"{ties} point(s) measured but in no survey: tie points")
    for p in points.values():
        if p.get("crs") == crs:
            p.pop("crs")
    options = {**sensors["options"], **req.options}  # the metadata's weights unless given
    if len(req.models) > 1:
        options["models"] = list(req.models)
    job: dict[str, Any] = {
        "schema_version": "1.0",
        "name": req.name,
        "crs": crs,
        "cameras": cameras,
        "images": images,
        "points": list(points.values()),
        "observations": observations,
    }
    if options:
        job["options"] = options
    if req.dem is not None:
        job["dem"] = dem_section(req.dem, req.dem_sigma_m, req.dem_vertical, dem_area(job))
        g = job["dem"]["grid"]
        notes.append(f"DEM {req.dem.name}: {g['rows']} x {g['columns']} cells, {g['vertical']}; sigma {req.dem_sigma_m:g} m")
    return Composed(job, notes)


DEM_MARGIN = 0.2  # of the area's extent added on each side (the points move; the images reach further)


def dem_area(job: dict[str, Any]) -> tuple[float, float, float, float] | None:
    """(west, south, east, north) degrees the job's images cover: the RPCs' ground domains
    (offset +- scale) and the points' coordinates, widened by DEM_MARGIN; None when unknown."""
    lon: list[float] = []
    lat: list[float] = []
    for im in job.get("images", []):
        rpc = im.get("rpc")
        if rpc:
            lon += [rpc["long_off"] - abs(rpc["long_scale"]), rpc["long_off"] + abs(rpc["long_scale"])]
            lat += [rpc["lat_off"] - abs(rpc["lat_scale"]), rpc["lat_off"] + abs(rpc["lat_scale"])]
    coords = [p for p in job.get("points", []) if p.get("coordinates")]
    if coords:
        xyz = np.array([p["coordinates"] for p in coords], dtype=float)
        crs = {p.get("crs", job.get("crs", DEFAULT_CRS)) for p in coords}
        if len(crs) == 1:
            from solver.geometry.geodesy import ecef_to_geodetic, to_ecef

            llh = ecef_to_geodetic(to_ecef(xyz, crs.pop()))
            lon += list(llh[:, 0])
            lat += list(llh[:, 1])
    if not lon:
        return None
    w, e, s, n = min(lon), max(lon), min(lat), max(lat)
    dx, dy = max(e - w, 1e-3) * DEM_MARGIN, max(n - s, 1e-3) * DEM_MARGIN
    return (w - dx, s - dy, e + dx, n + dy)


def dem_section(f: SourceFile, sigma_m: float, vertical: str | None, area: tuple[float, float, float, float] | None) -> dict[str, Any]:
    """The job's ``dem``: the DEM's window over ``area`` (the whole DEM when None) with its
    heights converted to ellipsoidal ones (:func:`solver.geometry.dem.grid_to_job`). A DEM that
    cannot be read, states no vertical datum, needs a geoid grid that is not here or does not
    cover the area is a located problem of the file."""
    from solver.geometry.dem import DemError, grid_to_job, read_dem
    from solver.geometry.vertical import VerticalDatumError

    if not (0.0 < sigma_m < float("inf")):
        raise fail("dem_sigma_m", 0, "", f"{sigma_m}: a positive number of metres is expected", "bad_argument")
    try:
        if f.path:
            dem = read_dem(f.path, vertical, bounds_lon_lat=area)
        else:  # an upload: a file of its own in a folder of its own, the only raster space of the read
            import tempfile
            from pathlib import Path

            from solver.raster_gate import RasterSpace, confined

            with tempfile.TemporaryDirectory(prefix="pba-dem-") as tmp:
                path = Path(tmp) / "dem.raster"
                path.write_bytes(f.data)
                with confined(RasterSpace.of(tmp)):
                    dem = read_dem(path, vertical, bounds_lon_lat=area)
            dem.source = f.name
    except (DemError, VerticalDatumError) as exc:
        raise fail(f.name, 0, "", str(exc), "unusable_dem") from None
    return {"grid": grid_to_job(dem), "sigma_m": float(sigma_m)}


def _measurements(
    f: SourceFile, image: str, req: ComposeRequest, surveyed: list[dict[str, Any]], crs: str,
    points: dict[str, dict[str, Any]], origin: dict[str, str], notes: list[str], problems: list[SourceProblem],
) -> list[dict[str, Any]]:
    kind = f.kind
    if kind == "csv":
        return read_measurements(f.data, f.name, image, f.columns, req.sigma_px)
    if kind == "qgis":
        obs, more = read_qgis_points(
            f.data, f.name, image, surveyed, crs, req.map_crs, req.sigma_px, req.match_tolerance_m
        )
        notes += more
        return obs
    if kind == "asp":
        return _asp(f, image, points, origin, crs, notes, problems)
    raise fail(f.name, 0, "", f"unknown measurement file type {PurePath(f.name).suffix!r} (.csv, .points, .gcp)")


def _named_measurements(f: SourceFile, image_ids: list[str], sigma_px: float, problems: list[SourceProblem]) -> list[dict[str, Any]]:
    """Observations of a measurement CSV whose ``image`` column names each row's image (the
    tie points ``pba match`` writes); a row naming an image not given is a located problem."""
    if f.kind != "csv":
        problems.append(SourceProblem(f.name, 0, "", "a measurement file without its image id (ID=FILE) must be a CSV "
                                      "whose image column names each row's image"))
        return []
    try:
        table = read_measurements(f.data, f.name, None, f.columns, sigma_px)
    except SourceError as exc:
        problems += exc.source_problems
        return []
    unknown = sorted({o["image"] for o in table} - set(image_ids))
    if unknown:
        problems.append(SourceProblem(f.name, 0, "image", f"image(s) {', '.join(map(repr, unknown))} not among the images given "
                                      f"({', '.join(image_ids)})"))
        return []
    return table


def _asp(
    f: SourceFile, image: str | None, points: dict[str, dict[str, Any]], origin: dict[str, str],
    crs: str, notes: list[str], problems: list[SourceProblem],
) -> list[dict[str, Any]]:
    """Observations of an ASP file (of ``image`` only when given: a file naming one image
    file is taken as that image's); its new points join ``points``."""
    try:
        pts, obs, more = read_asp_gcp(f.data, f.name)
    except SourceError as exc:
        problems += exc.source_problems
        return []
    notes += more
    if image is not None:
        named = {o["image"] for o in obs}
        if len(named) == 1:
            obs = [{**o, "image": image} for o in obs]
        else:
            obs = [o for o in obs if o["image"] == image]
    for p in pts:
        if p["id"] not in points:
            if crs != DEFAULT_CRS:
                p["crs"] = p.get("crs", DEFAULT_CRS)
            points[p["id"]] = p
            origin[p["id"]] = f.name
    return obs


def _rpc_image(im: ImageSources, req: ComposeRequest) -> dict[str, Any]:
    """An RPC image: ``{"id", "rpc", "model"}`` (no camera; time files given with it stay, for
    the solver's checks to refuse where they are)."""
    from solver.importers.rpc import read_rpc, read_rpc_bytes

    f = im.rpc
    rpc = read_rpc(f.path, shown=f.name) if f.path else read_rpc_bytes(f.data, f.name)
    out = {"id": im.id, "rpc": rpc.to_job(), "model": {"name": im.rpc_model or req.rpc_model}}
    if req.bias_prior_px is not None:
        priors = rpc_bias_priors(out["model"]["name"], out["rpc"], req.bias_prior_px)
        if priors is not None:
            out["bias_prior"] = priors
    return out


def rpc_bias_priors(model: str, rpc: dict[str, Any], sigma_px: float) -> dict[str, dict[str, float]] | None:
    """``images[].bias_prior`` putting 0 +- ``sigma_px`` on every bias term of an RPC image with
    bias model ``model`` (None for a name that is not an RPC bias model: validation says so).

    The offsets a0, b0 get ``sigma_px`` pixels; a drift term (px/px) gets ``sigma_px`` over the
    image's extent along its axis (twice the RPC's line or sample scale, the image's size), so
    that the term moves an image corner by at most about ``sigma_px`` too."""
    from solver.geometry.rpc import BIAS_MODELS

    names = BIAS_MODELS.get(model)
    if names is None:
        return None
    extent = {"line": 2.0 * abs(float(rpc["line_scale"])), "column": 2.0 * abs(float(rpc["samp_scale"]))}
    out = {}
    for name in names:
        if name in ("a0", "b0"):
            out[name] = {"value": 0.0, "sigma": float(sigma_px)}
        else:
            out[name] = {"value": 0.0, "sigma": float(sigma_px) / max(extent[name.split("_")[1]], 1.0)}
    return out


def _sensor_fragment(req: ComposeRequest, problems: list[SourceProblem]) -> dict[str, Any]:
    """The job fragment of the images given by vendor metadata (:mod:`solver.sensors`), read
    together so that they share one time scale: ``{"images": {id: image}, "cameras": [...],
    "options": {...}}``. Problems go into ``problems`` as ``file, element: message``."""
    given = [im for im in req.images if im.sensor is not None]
    if not given:
        return {"images": {}, "cameras": [], "options": {}}
    from solver.sensors.errors import MetadataError
    from solver.sensors.formats import read_product
    from solver.sensors.job_fragment import fragment

    products = []
    for im in given:
        f = im.sensor
        try:
            products.append(read_product(f.path or f.name, f.name, None if f.path else f.data))
        except MetadataError as exc:
            problems.append(SourceProblem(exc.file, 0, exc.element, exc.reason, "bad_sensor_metadata"))
    if len(products) < len(given):
        return {"images": {}, "cameras": [], "options": {}}
    doc = fragment(products, [im.id for im in given])
    return {"images": {i["id"]: i for i in doc["images"]}, "cameras": doc["cameras"], "options": doc["options"]}


def _image(im: ImageSources, req: ComposeRequest) -> dict[str, Any]:
    if im.rpc is not None:
        image = _rpc_image(im, req)
        if im.camera:
            image["camera"] = im.camera
    else:
        image = {"id": im.id, "camera": im.camera or req.camera or im.id, "model": {"name": req.models[0]}}
    scales: dict[str, str] = {}
    if im.state is not None:
        t, state, scales[im.state.name] = read_state(im.state.data, im.state.name, req.time_scale, im.state.columns)
        image["first_line_time_s"] = t
        image["approx_state"] = state
    if im.first_line_time_s is not None:
        image["first_line_time_s"] = im.first_line_time_s
    if im.ephemeris is not None:
        image["ephemeris"], scales[im.ephemeris.name] = read_ephemeris(
            im.ephemeris.data, im.ephemeris.name, req.time_scale, im.ephemeris.columns
        )
    if im.attitude is not None:
        image["attitude"], scales[im.attitude.name] = read_attitude(
            im.attitude.data, im.attitude.name, req.time_scale, im.attitude.columns
        )
    if im.attitude_base is not None:
        image["attitude_base"], scales[im.attitude_base.name] = read_attitude(
            im.attitude_base.data, im.attitude_base.name, req.time_scale, im.attitude_base.columns
        )
    if len(set(scales.values())) > 1:
        said = ", ".join(f"{k}: {v}" for k, v in scales.items())
        raise fail(next(iter(scales)), 1, "time_scale", f"the time files of image {im.id!r} state different time scales ({said})", "time_scale_mismatch")
    return image


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def _cameras(req: ComposeRequest, lookup: CameraLookup, problems: list[SourceProblem]) -> list[dict[str, Any]]:
    """The job cameras the images name, from camera files, presets or ``lookup``."""
    from_files: dict[str, dict[str, Any]] = {}
    for f in req.camera_files:
        try:
            doc = json.loads(f.data, parse_constant=_no_constant)
        except (ValueError, UnicodeDecodeError) as exc:
            problems.append(SourceProblem(f.name, getattr(exc, "lineno", 0), str(getattr(exc, "colno", "")), f"not JSON: {exc}"))
            continue
        except RecursionError:
            problems.append(SourceProblem(f.name, 0, "", "JSON nested too deeply", "nesting_too_deep"))
            continue
        items = doc if isinstance(doc, list) else doc.get("cameras", [doc]) if isinstance(doc, dict) else None
        if not isinstance(items, list) or not all(isinstance(c, dict) and isinstance(c.get("id"), str) for c in items):
            problems.append(SourceProblem(f.name, 0, "", "a camera file holds a camera object with an id, a list of them, or {\"cameras\": [...]}"))
            continue
        for c in items:
            from_files[c["id"]] = c
    out: list[dict[str, Any]] = []
    done: set[str] = set()
    for im in req.images:
        if im.rpc is not None and not im.camera:  # an RPC image needs no camera
            continue
        if im.sensor is not None:  # its metadata brings its camera
            continue
        name = im.camera or req.camera or im.id
        if name in done:
            continue
        done.add(name)
        if name in from_files:
            out.append(from_files[name])
            continue
        found = lookup(name)
        if found is None:
            problems.append(
                SourceProblem(
                    "camera", 0, "", f"unknown camera {name!r} for image {im.id!r}: not in the camera files given "
                    f"and not a preset ({', '.join(preset_names())}) or library camera", "unknown_camera",
                )
            )
            continue
        out.append({"id": name, **found})
    return out


def summarize(job: dict[str, Any]) -> dict[str, Any]:
    """What a job holds: per image the measured points by role, the points seen by one image
    only (``single_image``), measurements outside their image (``outside``: line or column
    beyond the pixel edges -0.5 .. size - 0.5) and surveyed points measured nowhere."""
    roles = {p["id"]: p.get("role", "tie") for p in job.get("points", [])}
    cams = {c["id"]: c for c in job.get("cameras", [])}
    size = {
        im["id"]: (cams.get(im.get("camera"), {}).get("lines"), cams.get(im.get("camera"), {}).get("columns"))
        for im in job.get("images", [])
        if isinstance(im.get("camera"), str)
    }
    per_image: dict[str, dict[str, int]] = {im["id"]: dict.fromkeys(ROLES, 0) for im in job.get("images", [])}
    seen_in: dict[str, set[str]] = {}
    outside: list[dict[str, Any]] = []
    for o in job.get("observations", []):
        role = roles.get(o["point"], "unknown")
        per_image.setdefault(o["image"], dict.fromkeys(ROLES, 0))
        per_image[o["image"]][role] = per_image[o["image"]].get(role, 0) + 1
        seen_in.setdefault(o["point"], set()).add(o["image"])
        lines, columns = size.get(o["image"], (None, None))
        if lines is not None and columns is not None and not (
            -0.5 <= o["line"] <= lines - 0.5 and -0.5 <= o["column"] <= columns - 0.5
        ):
            outside.append({"image": o["image"], "point": o["point"], "line": o["line"], "column": o["column"]})
    n_images = len(per_image)
    single = sorted(p for p, ims in seen_in.items() if len(ims) == 1) if n_images > 1 else []
    return {
        "images": per_image,
        "points": {r: sum(1 for v in roles.values() if v == r) for r in ROLES},
        "single_image": single,
        "single_image_ties": [p for p in single if roles.get(p) == "tie"],
        "outside": outside,
        "unmeasured": sorted(p for p, r in roles.items() if r != "tie" and p not in seen_in),
    }


def format_summary(summary: dict[str, Any]) -> list[str]:
    """The summary as lines of text (what ``pba job`` prints)."""
    out = [f"points: {summary['points']['gcp']} gcp, {summary['points']['check']} check, {summary['points']['tie']} tie"]
    for image, counts in summary["images"].items():
        out.append(f"image {image}: " + ", ".join(f"{counts.get(r, 0)} {r}" for r in ROLES) + " measured")
    if summary["single_image"]:
        ties = summary["single_image_ties"]
        out.append(
            f"{len(summary['single_image'])} point(s) seen by one image only: {', '.join(summary['single_image'][:20])}"
            + (f" ({len(ties)} of them tie points: they add no information)" if ties else "")
        )
    for o in summary["outside"][:20]:
        out.append(f"outside image {o['image']}: point {o['point']} at line {o['line']:.2f}, column {o['column']:.2f}")
    if summary["unmeasured"]:
        out.append(f"surveyed but measured in no image: {', '.join(summary['unmeasured'][:20])}")
    return out
