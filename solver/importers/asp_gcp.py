"""Ground control points and their image measurements from ASP ``bundle_adjust`` GCP files
(and back).

What the Ames Stereo Pipeline reads and writes (``.gcp``; ``stereo_gui``, ``gcp_gen``,
``bundle_adjust --save-cnet-as-csv``): one control point a line, fields separated by blanks or
commas, ``#`` comments (recent versions write ``# WKT: ...`` and column notes there)::

    # id lat lon height sigma_x sigma_y sigma_z image column row sigma_column sigma_row ...
    1 -21.998144 -51.194604 449.79 0.2 0.2 0.2 nadir.tif 13948.72 481.23 0.5 0.5 back.tif 13482.09 481.82 0.5 0.5

- id, then **latitude, longitude** (degrees; note the order: y before x) and height above the
  datum (metres; ASP's ``--datum``, WGS 84 for Earth: an ellipsoidal height). They become
  job points with coordinates (longitude, latitude, height) in ``datum_crs`` (default
  ``EPSG:4326``, the job schema's x/y order) and role ``gcp``.
- three standard deviations in metres. ASP applies them to ECEF x, y, z unless
  ``bundle_adjust --use-lon-lat-height-gcp-error`` is given (then to latitude, longitude,
  height). Ours are along east, north, up: ECEF sigmas are rotated into the local frame
  (``diag(R diag(s^2) R^T)``, correlations dropped; equal sigmas stay equal);
  latitude-longitude-height sigmas are reordered (north, east, up -> east, north, up). A
  ``# sigmas: lon-lat-height`` comment (what :func:`write_asp_gcp` writes) selects the second
  reading.
- per image: the image file name, column, row (pixels, from 0, integer values at pixel
  **centres**: ASP's (Vision Workbench's) pixel (0, 0) is the centre of the top-left pixel,
  the same origin as ours, so no shift), and their two standard deviations in pixels. Our
  ``sigma_px`` is one value: the larger of the two is taken (noted when they differ).
- the id: ASP documents an integer; ours are kept as written (any token without blanks or
  commas), and the writer notes ids that are not integers.
- the image file name becomes the job's image id by ``images`` (file name -> id), else its
  name without directory and extension (``/data/prism-nadir.tif`` -> ``prism-nadir``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import PurePath
from typing import Any

import numpy as np

from solver.geometry.geodesy import enu_rotation, from_ecef, to_ecef
from solver.importers.errors import SourceError, SourceProblem, fail
from solver.importers.tabular import collect, decode, fmt, parse_number

FIELDS = ("id", "latitude", "longitude", "height", "sigma_x", "sigma_y", "sigma_z")
PER_IMAGE = ("image", "column", "row", "sigma_column", "sigma_row")
SIGMA_FRAMES = ("xyz", "lon-lat-height")
_SPLIT = re.compile(r"[\s,]+")


def image_id_of(name: str, images: Mapping[str, str] | None = None) -> str:
    """The job image id of an ASP image file name."""
    if images and name in images:
        return images[name]
    return PurePath(name.replace("\\", "/")).stem or name


def read_asp_gcp(
    data: bytes | str,
    file: str,
    images: Mapping[str, str] | None = None,
    datum_crs: str = "EPSG:4326",
    sigma_frame: str | None = None,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[str]]:
    """(ground points, observations, notes) of a GCP file."""
    text = decode(data, file)
    frame = sigma_frame
    problems: list[SourceProblem] = []
    points: list[dict[str, Any]] = []
    obs: list[dict[str, Any]] = []
    notes: list[str] = []
    seen: dict[str, int] = {}
    for n, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = re.match(r"#\s*sigmas\s*:\s*(\S+)", s, re.I)
            if m and sigma_frame is None:
                frame = m.group(1).lower()
            continue
        try:
            p, o, note = _row(s, file, n, images, datum_crs, frame or "xyz")
        except SourceError as exc:
            problems += exc.source_problems
            continue
        if p["id"] in seen:
            problems.append(SourceProblem(file, n, "id", f"point {p['id']!r} is already on line {seen[p['id']]}"))
            continue
        seen[p["id"]] = n
        points.append(p)
        obs += o
        notes += note
    if frame not in (None, *SIGMA_FRAMES):
        problems.insert(0, SourceProblem(file, 0, "", f"unknown sigma frame {frame!r} ({', '.join(SIGMA_FRAMES)})"))
    collect(problems)
    return points, obs, notes


def _row(
    s: str, file: str, n: int, images: Mapping[str, str] | None, datum_crs: str, frame: str
) -> tuple[dict[str, Any], list[dict[str, Any]], list[str]]:
    tokens = [t for t in _SPLIT.split(s) if t]
    if len(tokens) < len(FIELDS) + len(PER_IMAGE) or (len(tokens) - len(FIELDS)) % len(PER_IMAGE):
        raise fail(
            file, n, "",
            f"{len(tokens)} fields: a GCP line has id, latitude, longitude, height, 3 sigmas, then 5 "
            "fields (image, column, row, 2 sigmas) per image",
        )
    num = [parse_number(tokens[i], file, n, f"{i + 1} ({FIELDS[i]})") for i in range(1, 7)]
    lat, lon, h = num[0], num[1], num[2]
    if not -90 <= lat <= 90:
        raise fail(file, n, f"2 ({FIELDS[1]})", f"latitude {lat!r} is outside -90..90 (ASP writes latitude first)")
    if not -360 <= lon <= 360:
        raise fail(file, n, f"3 ({FIELDS[2]})", f"longitude {lon!r} is outside -360..360")
    sig = num[3:]
    for i, v in enumerate(sig):
        if v <= 0:
            raise fail(file, n, f"{5 + i} ({FIELDS[4 + i]})", f"standard deviation {v!r} must be positive (metres)")
    point = {"id": tokens[0], "role": "gcp", "coordinates": [lon, lat, h], "sigma_m": _enu_sigmas(sig, lon, lat, frame)}
    if datum_crs != "EPSG:4326":
        point["crs"] = datum_crs
    observations: list[dict[str, Any]] = []
    notes: list[str] = []
    for k in range(len(FIELDS), len(tokens), len(PER_IMAGE)):
        g = tokens[k : k + len(PER_IMAGE)]
        col, row, sc, sr = (parse_number(g[j], file, n, f"{k + j + 1} ({PER_IMAGE[j]})") for j in range(1, 5))
        for j, v in ((3, sc), (4, sr)):
            if v <= 0:
                raise fail(file, n, f"{k + j + 1} ({PER_IMAGE[j]})", f"standard deviation {v!r} must be positive (pixels)")
        if not math.isclose(sc, sr, rel_tol=1e-9):
            notes.append(f"{file}, line {n}: column and row sigmas {sc:g}, {sr:g} px: the larger taken")
        observations.append(
            {"image": image_id_of(g[0], images), "point": tokens[0], "line": row, "column": col, "sigma_px": max(sc, sr)}
        )
    return point, observations, notes


def _enu_sigmas(sig: Sequence[float], lon: float, lat: float, frame: str) -> list[float]:
    """East, north, up standard deviations of ASP's three sigmas."""
    if frame == "lon-lat-height":
        s_lat, s_lon, s_h = sig  # ASP's order with --use-lon-lat-height-gcp-error: lat, lon, height
        return [s_lon, s_lat, s_h]
    r = enu_rotation(math.radians(lon), math.radians(lat))
    cov = r @ np.diag(np.square(sig)) @ r.T
    return [float(v) for v in np.sqrt(np.diag(cov))]


def write_asp_gcp(
    points: Sequence[dict[str, Any]],
    observations: Sequence[dict[str, Any]],
    points_crs: str,
    image_files: Mapping[str, str] | None = None,
    default_sigma_m: float = 1.0,
) -> tuple[str, list[str]]:
    """(GCP text, notes): one line per point with coordinates and at least one observation;
    latitude, longitude and ellipsoidal height on WGS 84; sigmas as latitude, longitude,
    height (a ``# sigmas: lon-lat-height`` comment; run ``bundle_adjust`` with
    ``--use-lon-lat-height-gcp-error``); image ids as file names by ``image_files``."""
    by_point: dict[str, list[dict[str, Any]]] = {}
    for o in observations:
        by_point.setdefault(o["point"], []).append(o)
    lines = [
        "# ASP bundle_adjust GCP file written by pba (pushbroom-ba)",
        "# sigmas: lon-lat-height (run bundle_adjust with --use-lon-lat-height-gcp-error)",
        "# id latitude longitude height sigma_lat sigma_lon sigma_height [image column row sigma_column sigma_row]...",
    ]
    notes: list[str] = []
    for p in points:
        if p.get("coordinates") is None or p["id"] not in by_point:
            notes.append(f"point {p['id']!r}: no coordinates or no observation, not written")
            continue
        if not p["id"].isdigit():
            notes.append(f"point {p['id']!r}: ASP documents integer GCP ids; renumber if bundle_adjust refuses it")
        xyz = np.array([p["coordinates"]], dtype=float)
        crs = p.get("crs") or points_crs
        lon, lat, h = (float(v) for v in (xyz[0] if crs == "EPSG:4326" else from_ecef(to_ecef(xyz, crs), "EPSG:4979")[0]))
        se, sn, su = p.get("sigma_m") or [default_sigma_m] * 3
        fields = [p["id"], fmt(lat), fmt(lon), fmt(h), fmt(float(sn)), fmt(float(se)), fmt(float(su))]
        for o in by_point[p["id"]]:
            name = (image_files or {}).get(o["image"], o["image"])
            s = float(o.get("sigma_px", 0.5))
            fields += [name, fmt(float(o["column"])), fmt(float(o["line"])), fmt(s), fmt(s)]
        lines.append(" ".join(fields))
    return "\n".join(lines) + "\n", notes
