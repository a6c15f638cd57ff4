"""Use cases of the GIS result endpoints (service/routes/gis.py): the adjusted model of a
finished job (solver.gis, rebuilt from the stored job document and report) and what it answers:
RPC files, GeoJSON, ground <-> image transforms. No mathematics here: every number comes from
:mod:`solver.gis`.

The adjusted model of a job and its fitted RPCs are kept in small per-process caches (a report
never changes): an RPC is fitted once per job, image and kind (whole image or per chip), and
concurrent requests for the same one wait for that one fit.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any

from service.errors import Conflict, InvalidInput, NotFound
from service.jobs import results_text
from service.store import JobRecord
from solver.errors import JobError
from solver.geometry.geodesy import UnknownCRSError
from solver.gis.model import AdjustedImage, AdjustedModel, ModelMismatch, load_model

CACHED_MODELS = 8
CACHED_RPCS = 64  # (job, image, per chip) entries


class NotAnAdjustment(Conflict):
    code, title = "not-an-adjustment", "The job's report has no single adjusted orientation"


class NoSuchImage(NotFound):
    code, title = "no-such-image", "No such image in the job"


_lock = threading.Lock()
_models: OrderedDict[str, AdjustedModel] = OrderedDict()
_rpcs: OrderedDict[tuple[str, str, bool], list[Any]] = OrderedDict()
_fitting: dict[tuple[str, str, bool], threading.Lock] = {}


def adjusted_model(rec: JobRecord) -> AdjustedModel:
    """The adjusted model of a successful adjustment job (the OGC result errors otherwise)."""
    results_text(rec)  # 404 result-not-ready / job-failed problems for unfinished jobs
    with _lock:
        model = _models.get(rec.id)
        if model is not None:
            _models.move_to_end(rec.id)
            return model
    report = rec.results
    document = rec.document or {}
    if not isinstance(report, dict) or report.get("kind") != "adjustment" or "job" not in document:
        raise NotAnAdjustment(
            "ground/image transforms, RPCs and GeoJSON need the report of one adjustment "
            "(a model comparison has one report per model: run the chosen model as its own job)"
        )
    try:
        model = load_model(document["job"], report)
    except (ModelMismatch, JobError) as exc:
        raise NotAnAdjustment(f"the job's adjusted model cannot be rebuilt: {exc}") from exc
    with _lock:
        _models[rec.id] = model
        while len(_models) > CACHED_MODELS:
            _models.popitem(last=False)
    return model


def image_of(model: AdjustedModel, image_id: str) -> AdjustedImage:
    try:
        return model.image(image_id)
    except KeyError as exc:
        raise NoSuchImage(str(exc.args[0])) from exc


def chip_ids(image: Any) -> list[str]:
    """The chip ids of an adjusted image (``["1"]`` for a single-array camera or an RPC image)."""
    camera = getattr(getattr(image, "image", None), "camera", None)
    return [c.id for c in getattr(camera, "chips", None) or []] or ["1"]


def fitted_rpcs(rec: JobRecord, model: AdjustedModel, image: Any, per_chip: bool) -> list[Any]:
    """The RPCs of ``image`` (one, or one per chip), fitted once per job and cached."""
    from solver.gis.rpc_export import image_rpcs

    key = (rec.id, image.id, per_chip)
    with _lock:
        lock = _fitting.setdefault(key, threading.Lock())
    with lock:  # one fit per key; the others wait for it and read the cache
        with _lock:
            found = _rpcs.get(key)
            if found is not None:
                _rpcs.move_to_end(key)
                return found
        rpcs = image_rpcs(model, image, per_chip=per_chip)
        with _lock:
            _rpcs[key] = rpcs
            _fitting.pop(key, None)
            while len(_rpcs) > CACHED_RPCS:
                _rpcs.popitem(last=False)
    return rpcs


def rpc_document(rec: JobRecord, image_id: str, fmt: str, chip: str | None) -> tuple[str, dict[str, Any]]:
    """(file text, fit record) of the image's RPC (one chip's with ``chip``: an unknown chip is
    a 404 before anything is fitted)."""
    from solver.gis.rpc_io import render

    model = adjusted_model(rec)
    image = image_of(model, image_id)
    if chip is not None and chip not in (ids := chip_ids(image)):
        raise NoSuchImage(f"image {image_id!r} has no chip {chip!r} (chips: {', '.join(ids)})")
    rpcs = fitted_rpcs(rec, model, image, chip is not None)
    if chip is not None:
        rpcs = [r for r in rpcs if r.fit["chip"] == chip]
    return render(rpcs[0], fmt), rpcs[0].fit


def geojson(rec: JobRecord) -> dict[str, Any]:
    from solver.gis.geojson import results_geojson

    return results_geojson(adjusted_model(rec))


def _rows_problem(exc: Exception, where: str) -> InvalidInput:
    text = str(exc)
    pointer = f"/{where}"
    if text.startswith("row "):
        try:
            pointer = f"/{where}/{int(text.split()[1].rstrip(',:')) - 1}"
        except ValueError:
            pass
    return InvalidInput(text, errors=[{"pointer": pointer, "code": "invalid_value", "message": text}])


def ground_to_image(rec: JobRecord, image_id: str, points: list[dict[str, Any]], crs: str, sigmas: bool) -> list[dict[str, Any]]:
    from solver.gis.transforms import TableError, ground_to_image_table

    image = image_of(adjusted_model(rec), image_id)
    try:
        return ground_to_image_table(image, points, crs, sigmas)
    except TableError as exc:
        raise _rows_problem(exc, "points") from exc
    except UnknownCRSError as exc:
        raise InvalidInput(str(exc), errors=[{"pointer": "/crs", "code": "unknown_crs", "message": str(exc)}]) from exc


def image_to_ground(rec: JobRecord, image_id: str, pixels: list[dict[str, Any]], crs: str, sigmas: bool) -> list[dict[str, Any]]:
    from solver.gis.transforms import TableError, image_to_ground_table

    image = image_of(adjusted_model(rec), image_id)
    try:
        return image_to_ground_table(image, pixels, crs, None, sigmas)
    except TableError as exc:
        raise _rows_problem(exc, "pixels") from exc
    except UnknownCRSError as exc:
        raise InvalidInput(str(exc), errors=[{"pointer": "/crs", "code": "unknown_crs", "message": str(exc)}]) from exc
