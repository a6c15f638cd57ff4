"""Results for GIS tools on a finished adjustment (service/gis_results.py, solver/gis/), computed
in the GIS process (service/gis_process.py), never in the API process:

- ``GET /jobs/{jobId}/results/rpc/{image}?format=txt|rpb[&chip=ID]``: the RPC00B fitted to the
  adjusted model, as GDAL's ``_RPC.TXT`` or an ``.RPB`` (download; fit residuals in headers);
- ``GET /jobs/{jobId}/results/geojson``: points, discrepancy vectors, footprints (CRS84);
- ``POST /jobs/{jobId}/results/ground-to-image`` and ``.../image-to-ground``: the transforms of
  ``pba ground-to-image`` / ``pba image-to-ground`` on rows given as JSON objects.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from service.deps import CurrentUser, ServicesDep, VisibleJob
from service.errors import problem_responses

router = APIRouter(prefix="/jobs", tags=["gis"])

MAX_ROWS = 10_000
Row = dict[str, float | str | None]


class GroundToImageRequest(BaseModel):
    """Ground points of one image: ``points`` rows with the CRS's columns (EPSG:4979: lon, lat,
    height); each row comes back with ``line``, ``column`` (pixel centres, origin at the centre
    of the top-left pixel) and, with ``sigmas``, ``sigma_line_px``, ``sigma_column_px``."""

    model_config = ConfigDict(extra="forbid")
    image: str = Field(min_length=1, max_length=200)
    crs: str = Field(default="EPSG:4979", max_length=2000)
    sigmas: bool = False
    points: list[Row] = Field(min_length=1, max_length=MAX_ROWS)


class ImageToGroundRequest(BaseModel):
    """Image positions of one image: ``pixels`` rows with ``line``, ``column``, ``height``
    (ellipsoidal metres); each row comes back with the CRS's columns and, with ``sigmas``,
    ``sigma_east_m``, ``sigma_north_m``."""

    model_config = ConfigDict(extra="forbid")
    image: str = Field(min_length=1, max_length=200)
    crs: str = Field(default="EPSG:4979", max_length=2000)
    sigmas: bool = False
    pixels: list[Row] = Field(min_length=1, max_length=MAX_ROWS)


class TransformResult(BaseModel):
    jobID: str
    image: str
    crs: str
    rows: list[dict[str, Any]]


RPC_MEDIA = "text/plain"
FormatQuery = Annotated[Literal["txt", "rpb"], Query(description="txt: GDAL's NAME_RPC.TXT sidecar; rpb: NAME.RPB")]
ChipQuery = Annotated[str | None, Query(max_length=64, description="one CCD chip's RPC (columns of the chip's sub-image)")]


@router.get(
    "/{jobId}/results/rpc/{image}",
    response_class=Response,
    responses={200: {"description": "the RPC file", "content": {RPC_MEDIA: {"schema": {"type": "string"}}}}, **problem_responses(401, 404, 409, 503)},
)
async def get_rpc(job: VisibleJob, user: CurrentUser, services: ServicesDep, image: str, format: FormatQuery = "txt", chip: ChipQuery = None) -> Response:
    """The RPC00B of one adjusted image fitted to the adjusted rigorous model. Its image
    coordinates put the centre of the top-left pixel at (0, 0); GDAL's transformer adds half a
    pixel. Headers: ``X-RPC-Check-RMS-Px``, ``X-RPC-Check-Max-Px`` (fit on an independent check
    grid) and a ``Warning`` for the whole-image RPC of a multi-chip image."""
    text, fit = await services.gis.call("rpc_document", job.id, image, format, chip or None, owner=user.id)
    stem = image if chip is None else f"{image}_{chip}"
    name = f"{stem}_RPC.TXT" if format == "txt" else f"{stem}.RPB"
    headers = {
        "Content-Disposition": f'attachment; filename="{name}"',
        "X-RPC-Check-RMS-Px": f"{fit['check_residuals']['rms_px']:.3g}",
        "X-RPC-Check-Max-Px": f"{fit['check_residuals']['max_px']:.3g}",
    }
    if fit["warnings"]:
        headers["Warning"] = '199 pba "' + fit["warnings"][0].replace('"', "'") + '"'
    return Response(text, media_type=RPC_MEDIA, headers=headers)


@router.get(
    "/{jobId}/results/geojson",
    response_class=JSONResponse,
    responses={200: {"description": "GeoJSON FeatureCollection", "content": {"application/geo+json": {"schema": {"type": "object"}}}}, **problem_responses(401, 404, 409, 503)},
)
async def get_geojson(job: VisibleJob, user: CurrentUser, services: ServicesDep) -> JSONResponse:
    """Control, check and tie points (residual and discrepancy vectors, predicted precision)
    and image footprints as a GeoJSON FeatureCollection (CRS84)."""
    doc = await services.gis.call("geojson", job.id, owner=user.id)
    return JSONResponse(doc, media_type="application/geo+json")


@router.post("/{jobId}/results/ground-to-image", response_model=TransformResult, responses=problem_responses(401, 404, 409, 422, 503))
async def post_ground_to_image(job: VisibleJob, user: CurrentUser, services: ServicesDep, body: GroundToImageRequest) -> TransformResult:
    """Image positions of ground points with the adjusted rigorous model."""
    rows = await services.gis.call("ground_to_image", job.id, body.image, body.points, body.crs, body.sigmas, owner=user.id, rows=len(body.points))
    return TransformResult(jobID=job.id, image=body.image, crs=body.crs, rows=rows)


@router.post("/{jobId}/results/image-to-ground", response_model=TransformResult, responses=problem_responses(401, 404, 409, 422, 503))
async def post_image_to_ground(job: VisibleJob, user: CurrentUser, services: ServicesDep, body: ImageToGroundRequest) -> TransformResult:
    """Ground coordinates of image positions at given ellipsoidal heights."""
    rows = await services.gis.call("image_to_ground", job.id, body.image, body.pixels, body.crs, body.sigmas, owner=user.id, rows=len(body.pixels))
    return TransformResult(jobID=job.id, image=body.image, crs=body.crs, rows=rows)
