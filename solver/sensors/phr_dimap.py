"""Pleiades 1A/1B ground-segment metadata (root ``PHR_Dimap_Document``, ``METADATA_FORMAT``
``DIMAP_PHR``, processing level ``SENSOR``) read into the exact linescan model, with the global
RFM (the product's RPC) that the same file carries.

The format is the one CNES' Pleiades ground segment writes beside a sensor product (e.g. the
``PHRDIMAP_*.XML`` files of CNES' shareloc tests); its sensor model holds what a DIMAP v2
``Refined_Model`` holds under other names (:mod:`solver.sensors.dimap_v2`; on two real Pleiades
1B products the exact model meets the file's own RFM to 0.001 and 0.006 px RMS, docs/sensor-metadata.md):

- ``Raster_Dimensions``: ``NROWS``, ``NCOLS``;
- ``Geometric_Data/Sensor_Model_Characteristics``:
  ``UTC_Sensor_Model_Range/START`` (UTC: the first line's time), ``SENSOR_LINE_PERIOD`` (ms);
  ``Sensor_Ephemeris/Point_List/Point`` with ``LOCATION_VALUES`` (ECEF m), ``VELOCITY_VALUES``
  (m/s), ``UTC_TIME``; ``Sensor_Attitudes``: ``Polynomial_Models/Q0..Q3`` (``DEGREE``,
  ``COEFFICIENTS``, lowest degree first) in ``(t - OFFSET) / SCALE`` with ``OFFSET`` and
  ``SCALE`` beside them (t in s after 00:00 UTC), satellite frame to ECEF;
  ``Sensor_Viewing_Model``: ``Position_In_Retina/FIRST_COL`` and
  ``Viewing_Directions/PsiX_Model``, ``PsiY_Model`` (``DEGREE``, ``COEFFICIENTS``): the DIMAP v2
  look-angle polynomials ``XLOS`` and ``YLOS`` (equal values on products of both formats);
- ``Geoposition/Rational_Sensor_Model/Global_RFM``: ``Inverse_Model`` ``F_COL``, ``F_ROW`` (20
  numerator then 20 denominator coefficients in the RPC00B term order, of longitude, latitude
  and height normalised by ``RFM_Validity`` ``Lon``, ``Lat``, ``Alt`` with ``A`` the scale and
  ``B`` the offset), giving 1-based pixel-centre columns and rows (``Col``, ``Row``);
- ``Product_Frame/Dataset_Frame``: the ``Vertex`` and ``Center`` corners (as DIMAP v2's extent).
"""

from __future__ import annotations

from datetime import datetime

import numpy as np

from solver.geometry.rpc import RPC
from solver.schema.job import MAX_COLUMNS, MAX_LINES
from solver.sensors.detectors import DIMAP_V2_SATELLITE, LookAngles
from solver.sensors.dimap_v2 import (
    DEFAULT_PIXEL_MM,
    DimapV2Product,
    checked_line_period,
    extent_rows,
    linescan_model,
    polynomial_coefficients,
    polynomial_quaternions,
)
from solver.sensors.maxar import parse_utc
from solver.sensors.xmlsafe import Node

FORMAT = "DIMAP_PHR"
EPHEMERIS_TAGS = ("LOCATION_VALUES", "VELOCITY_VALUES", "UTC_TIME")
RFM_TERMS = 20


def _look_angles(viewing: Node) -> LookAngles:
    first_col = viewing.child("Position_In_Retina").number("FIRST_COL")
    directions = viewing.child("Viewing_Directions")
    across, along = polynomial_coefficients(directions, "PsiX_Model"), polynomial_coefficients(directions, "PsiY_Model")
    return LookAngles.polynomials(along, across, first_col - 1.0, DIMAP_V2_SATELLITE)


def _line_period(model: Node) -> float:
    node = model.child("SENSOR_LINE_PERIOD")
    unit = (node.element.get("unit") or "ms").strip().lower()
    if unit not in ("ms", "s"):
        raise node.error(f"unit {unit[:20]!r}: ms or s expected")
    return checked_line_period(node, model.number("SENSOR_LINE_PERIOD") * (1e-3 if unit == "ms" else 1.0))


def read_rfm(root: Node) -> RPC:
    """The global RFM's inverse model (ground to image) as an RPC with 0-based pixel centres."""
    rfm = root.child("Geoposition").child("Rational_Sensor_Model").child("Global_RFM")
    inverse = rfm.child("Inverse_Model")
    col = inverse.numbers("F_COL", 2 * RFM_TERMS)
    row = inverse.numbers("F_ROW", 2 * RFM_TERMS)
    validity = rfm.child("RFM_Validity")
    scale, offset = {}, {}
    for name in ("Lon", "Lat", "Alt", "Col", "Row"):
        node = validity.child(name)
        scale[name], offset[name] = node.number("A"), node.number("B")
        if scale[name] == 0.0:
            raise node.error("a scale of 0", "A")
    return RPC(
        line_off=offset["Row"] - 1.0, samp_off=offset["Col"] - 1.0, lat_off=offset["Lat"], long_off=offset["Lon"],
        height_off=offset["Alt"], line_scale=scale["Row"], samp_scale=scale["Col"], lat_scale=scale["Lat"],
        long_scale=scale["Lon"], height_scale=scale["Alt"],
        line_num=np.array(row[:RFM_TERMS]), line_den=np.array(row[RFM_TERMS:]),
        samp_num=np.array(col[:RFM_TERMS]), samp_den=np.array(col[RFM_TERMS:]),
    )


def read_phr_dimap_root(root: Node, shown: str) -> DimapV2Product:
    """The product of a parsed ``PHR_Dimap_Document`` (module docstring)."""
    ident = root.child("Metadata_Identification")
    if ident.text("METADATA_FORMAT") != FORMAT:
        raise ident.error(f"{ident.text('METADATA_FORMAT')[:40]}: {FORMAT} expected", "METADATA_FORMAT")
    level = root.child("Product_Characteristics").text("PROCESSING_LEVEL")
    if level != "SENSOR":
        raise root.error(f"{level[:40]}: a SENSOR product expected (an ortho product has no sensor model)",
                         "Product_Characteristics/PROCESSING_LEVEL")
    dims = root.child("Raster_Dimensions")
    lines, columns = dims.integer("NROWS"), dims.integer("NCOLS")
    if not (2 <= lines <= MAX_LINES and 1 <= columns <= MAX_COLUMNS):
        raise dims.error(f"NROWS {lines}, NCOLS {columns}: 2 to {MAX_LINES} rows and 1 to {MAX_COLUMNS} columns expected")
    model = root.child("Geometric_Data").child("Sensor_Model_Characteristics")
    time = model.child("UTC_Sensor_Model_Range")
    first_line = parse_utc(time, "START")
    period = _line_period(model)
    att = model.child("Sensor_Attitudes")
    look = _look_angles(model.child("Sensor_Viewing_Model"))

    def attitude(epoch: datetime, span: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        return polynomial_quaternions(att.child("Polynomial_Models"), att, epoch, first_line, span)

    exact, screening = linescan_model(model.child("Sensor_Ephemeris").child("Point_List"), EPHEMERIS_TAGS, att, attitude, time,
                           first_line, period, lines, columns, look)
    frame = root.child("Product_Frame").find("Dataset_Frame")
    corners = extent_rows(frame) if frame is not None else np.zeros((0, 5))
    return DimapV2Product(shown, "Pleiades", "P", FORMAT, exact, look, period, DEFAULT_PIXEL_MM, corners, None, None,
                          rpc=read_rfm(root), screening=screening)


def is_phr_dimap(head: bytes) -> bool:
    return b"<PHR_Dimap_Document" in head
