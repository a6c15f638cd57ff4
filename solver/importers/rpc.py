"""``pba import-rpc``: an RPC00B that GDAL reads, as the job's ``images[].rpc`` object.

Sources (read by GDAL through rasterio, never by our own parsers, except the RPB element of a
Maxar support-data XML, which GDAL reads only beside its raster, and the RFM of the Pleiades
ground segment's metadata, which GDAL does not read):

- a raster (``IMAGE.tif`` and anything else GDAL opens): its RPC metadata domain, i.e. GeoTIFF
  RPC tags, or the sidecar GDAL finds beside it (``IMAGE_RPC.TXT``, ``IMAGE.RPB``, a DIMAP
  product's ``RPC_*.XML``), or a format's own (NITF RPC00B, a DIMAP ``DIM_*.XML``);
- a bare sidecar: ``NAME_RPC.TXT`` (GDAL's RPC text), ``NAME.RPB`` (DigitalGlobe style), an
  ALOS ``RPC-<scene>.txt`` (one fixed-width line), a DIMAP RPC XML (``RPC_*.XML``,
  Pleiades/SPOT 6-7 ``Rational_Function_Model``), a DIMAP v2 metadata file (``DIM_*.XML``
  or renamed: the RPC component it names, beside it), or a Maxar support-data XML (root
  ``isd``: its ``RPB`` element, read by :mod:`solver.sensors.maxar` since GDAL reads it only
  beside the raster), or a Pleiades ground-segment metadata file (root ``PHR_Dimap_Document``:
  its global RFM, read by :mod:`solver.sensors.phr_dimap`; GDAL does not read it). GDAL reads
  those only beside a raster, so the file is copied into a temporary directory beside a 1 x 1
  GeoTIFF under the names GDAL looks for, and GDAL reads that raster's RPC.

Pixel convention. GDAL's RPC metadata holds RPC00B's convention: the centre of the top-left
pixel at (0, 0) (GDAL converts DIMAP's 1-based ``LINE_OFF``/``SAMP_OFF`` itself, from
``FIRST_COL`` when the file has it). That is ours, so the object is written with
``"pixel_convention": "center"`` unchanged; ``pixel_convention="gdal"`` writes GDAL's
transformer convention instead (``line_off`` and ``samp_off`` + 0.5 px, converted once here;
the solver converts it back when it reads the job, :meth:`solver.geometry.rpc.RPC.from_job`).
"""

from __future__ import annotations

import shutil
import tempfile
import warnings
from pathlib import Path, PurePath
from typing import Any

from solver.geometry.rpc import RPC
from solver.importers.errors import fail
from solver.raster_gate import RasterSpace, confined
from solver.sensors.errors import MetadataError
from solver.sensors.maxar import is_maxar_xml, read_maxar_rpc

SIDECAR_KINDS = ("txt", "rpb", "dimap", "alos")


def sidecar_kind(path: Path) -> str | None:
    """``alos``, ``txt``, ``rpb`` or ``dimap`` for a bare RPC file (by name), None for anything else."""
    name = path.name.lower()
    if name.startswith("rpc-") and name.endswith(".txt"):  # ALOS PRISM/AVNIR-2: RPC-<scene>.txt, one fixed-width line
        return "alos"
    if name.endswith(".txt"):  # NAME_RPC.TXT (any .txt is tried as GDAL's RPC text)
        return "txt"
    if name.endswith(".rpb"):
        return "rpb"
    if name.endswith(".xml"):  # an RPC_*.XML, or a DIMAP metadata file naming its RPC component
        return "dimap"
    return None


def _dummy_raster(path: Path) -> None:
    import numpy as np

    from solver.raster_gate import create_raster

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NotGeoreferencedWarning
        with create_raster(path, driver="GTiff", width=1, height=1, count=1, dtype="uint8") as dst:
            dst.write(np.zeros((1, 1, 1), np.uint8))


def rpc_sidecar_names(raster: Path) -> tuple[str, ...]:
    """The sidecars GDAL's metadata readers take an RPC from beside ``raster``: ``NAME_RPC.TXT``,
    ``NAME.RPB``, a DigitalGlobe ``NAME.XML`` or ``NAME.IMD``, a DIMAP product's ``RPC_<x>.XML``
    beside ``IMG_<x>``, an ALOS ``RPC-<x>.txt`` (with its ``summary.txt``) beside ``IMG-<x>``;
    the raster gate lets GDAL see these only."""
    from solver.raster_gate import RPC_SIDECARS

    stem = raster.stem
    names = [*RPC_SIDECARS, f"{stem}.XML", f"{stem}.xml", f"{stem}.IMD", f"{stem}.imd"]
    if stem[:4].upper() == "IMG_":
        names += [f"RPC_{stem[4:]}.XML", f"RPC_{stem[4:]}.xml"]
    if stem[:4].upper() == "IMG-":
        names += [f"RPC-{stem[4:]}.txt", f"RPC-{stem[4:]}.TXT", "summary.txt"]
    return tuple(names)


def _gdal_rpcs(raster: Path, shown: str) -> RPC:
    """The RPC GDAL reads from ``raster`` or its sidecars, through the raster gate."""
    from solver.raster_gate import RasterRefused, open_raster

    try:
        with open_raster(raster, shown=shown, sidecars=rpc_sidecar_names(raster)) as gated:
            rpcs = gated.dataset.rpcs
    except RasterRefused as exc:
        raise fail(shown, 0, "", f"GDAL cannot open it: {exc.message}") from None
    except (KeyError, ValueError) as exc:  # rasterio's RPC of a file GDAL half-reads (an XML without RPC fields)
        raise fail(shown, 0, "", f"GDAL reads an incomplete RPC from it (missing or unreadable: {exc})", "incomplete_rpc") from None
    if rpcs is None:
        raise fail(shown, 0, "", "GDAL finds no RPC in it (no RPC tags, no readable _RPC.TXT, .RPB or RPC XML)")
    try:
        return RPC.from_gdal(rpcs.to_gdal())
    except (KeyError, ValueError) as exc:
        raise fail(shown, 0, "", f"incomplete RPC: {exc}") from None


def read_rpc_bytes(data: bytes | str, name: str) -> RPC:
    """The RPC of an uploaded bare RPC file (its bytes and the name it was given, which decides
    the reader: ``NAME_RPC.TXT``, ``NAME.RPB``, a DIMAP RPC XML), through GDAL, as
    :func:`read_rpc`. The name is never opened as a path: the bytes are written under its last
    component into a temporary directory first. Rasters are refused: an upload goes through the
    server's own process, and a raster's RPC is a small sidecar the caller can send instead
    (``pba import-rpc`` reads rasters on the caller's machine)."""
    base = PurePath(name.replace("\\", "/")).name or "upload"
    if base in (".", "..") or sidecar_kind(Path(base)) is None:
        raise fail(name, 0, "", "an uploaded RPC is a NAME_RPC.TXT, NAME.RPB, ALOS RPC-*.txt or DIMAP RPC_*.XML file (by its name); "
                   "for a raster's RPC, send its sidecar or the output of pba import-rpc", "not_an_rpc_file")
    with tempfile.TemporaryDirectory(prefix="pba-rpc-upload-") as tmp:
        # a fixed name of the same kind: an upload's own name may hold NUL or exceed NAME_MAX
        path = Path(tmp) / (("rpc-upload" if sidecar_kind(Path(base)) == "alos" else "upload") + PurePath(base).suffix.lower())
        path.write_bytes(data.encode() if isinstance(data, str) else data)
        return read_rpc(path, shown=name)


def read_rpc(path: str | Path, shown: str | None = None) -> RPC:
    """The RPC of a raster or a bare RPC file (module docstring), through GDAL; our pixel
    convention. Raises :class:`solver.importers.errors.SourceError` naming the file (``shown``,
    default its path)."""
    path = Path(path)
    shown = str(path) if shown is None else shown
    if not path.is_file():
        raise fail(shown, 0, "", "no such file")
    kind = sidecar_kind(path)
    if kind is None:
        return _gdal_rpcs(path, shown)
    if kind == "dimap" and is_maxar_xml(path):  # GDAL reads a Maxar XML's RPB only beside its raster
        return _maxar_rpc(path, shown)
    if kind == "dimap" and _is_phr_dimap(path):  # GDAL does not read this format's RFM
        return _phr_dimap_rfm(path, shown)
    if kind == "dimap":
        component = _dimap_metadata_rpc(path, shown)
        if component is not None:  # a DIM_*.XML: its RPC is a file of its own beside it
            return read_rpc(component, f"{shown} (its RPC component {component.name})")
    with tempfile.TemporaryDirectory(prefix="pba-rpc-") as tmp:
        d = Path(tmp)
        # the names GDAL's readers look for beside a raster (GDALMDReaderPleiades: IMG_<x>_R1C1
        # -> RPC_<x>_R1C1.XML; GDALMDReaderALOS: IMG-<x> -> RPC-<x>.txt, with a summary.txt)
        raster = d / {"dimap": "IMG_PBA_R1C1.tif", "alos": "IMG-PBA.tif"}.get(kind, "image.tif")
        sidecar = {"txt": d / "image_RPC.TXT", "rpb": d / "image.RPB", "dimap": d / "RPC_PBA_R1C1.XML", "alos": d / "RPC-PBA.txt"}[kind]
        _dummy_raster(raster)
        shutil.copyfile(path, sidecar)
        if kind == "alos":
            (d / "summary.txt").write_text("")
        with confined(RasterSpace.of(d)):  # the temporary folder is this read's whole space
            return _gdal_rpcs(raster, shown)


def _dimap_metadata_rpc(path: Path, shown: str) -> Path | None:
    """None for an RPC XML; for a DIMAP v2 metadata file (``Dimap_Document`` without an RPC
    model of its own) the RPC component's file beside it, or a located error when it is not
    there (GDAL reads that component only beside the product's rasters)."""
    from solver.sensors.dimap_v2 import rpc_component
    from solver.sensors.xmlsafe import load

    try:
        root = load(path, shown)
    except MetadataError as exc:
        raise fail(shown, 0, exc.element, exc.reason) from None
    if root.element.tag != "Dimap_Document" or root.element.find(".//Global_RFM") is not None \
            or root.element.find("Geometric_Data") is None and root.element.find("Dataset_Content") is None:
        return None
    name = rpc_component(root)
    if name is None:
        raise fail(shown, 0, "Dataset_Content/Dataset_Components", "a DIMAP metadata file without an RPC model or an RPC "
                   "component: give the product's RPC_*.XML", "no_rpc")
    beside = path.parent / name
    if not beside.is_file() or beside.resolve() == path.resolve():
        raise fail(shown, 0, "Dataset_Content/Dataset_Components", f"a DIMAP metadata file: its RPC is the component {name}, "
                   "not found beside it; give that file", "no_rpc")
    return beside


def _is_phr_dimap(path: Path) -> bool:
    from solver.sensors.phr_dimap import is_phr_dimap

    with open(path, "rb") as f:
        return is_phr_dimap(f.read(4096))


def _phr_dimap_rfm(path: Path, shown: str) -> RPC:
    """The global RFM of a Pleiades ground-segment metadata file (:mod:`solver.sensors.phr_dimap`)."""
    from solver.sensors.phr_dimap import read_rfm
    from solver.sensors.xmlsafe import load

    try:
        return read_rfm(load(path, shown))
    except MetadataError as exc:
        raise fail(shown, 0, exc.element, exc.reason) from None


def _maxar_rpc(path: Path, shown: str) -> RPC:
    """The RPB element of a Maxar support-data XML (:mod:`solver.sensors.maxar`, parsed safely)."""
    try:
        return read_maxar_rpc(path, shown)
    except MetadataError as exc:
        raise fail(shown, 0, exc.element, exc.reason) from None


def rpc_object(path: str | Path, pixel_convention: str = "center") -> dict[str, Any]:
    """The job's ``images[].rpc`` object of a file GDAL reads."""
    return read_rpc(path).to_job(pixel_convention)


def image_entry(path: str | Path, image_id: str, model: str, pixel_convention: str = "center") -> dict[str, Any]:
    """A whole RPC image of the job: ``{"id", "rpc", "model": {"name"}}`` (no camera)."""
    return {"id": image_id, "rpc": rpc_object(path, pixel_convention), "model": {"name": model}}
