"""Which reader a metadata file needs, by its root element: ``isd`` (Maxar support data,
:mod:`solver.sensors.maxar`), ``Dimap_Document`` (DIMAP v1 of SPOT 1-5,
:mod:`solver.sensors.dimap_spot5`; DIMAP v2 of SPOT 6/7 and Pleiades,
:mod:`solver.sensors.dimap_v2`, told apart by ``METADATA_FORMAT``'s version),
``PHR_Dimap_Document`` (Pleiades ground-segment metadata, :mod:`solver.sensors.phr_dimap`) or ``prdf`` (INPE
product XML of CBERS-4/4A and Amazonia-1: :mod:`solver.sensors.inpe_cbers`; ``FILE#left`` or
``FILE#right`` names the camera of a two-camera record, the left one by default, and ``#raw``
(``FILE#raw``, ``FILE#right,raw``) declares that the image measurements are in the raw image the
record describes, not in the map-projected raster INPE delivers)."""

from __future__ import annotations

from pathlib import Path

from solver.sensors.dimap_spot5 import Spot5Product, dimap_version, read_dimap_v1_root
from solver.sensors.dimap_v2 import DimapV2Product, read_dimap_v2_root
from solver.sensors.errors import MetadataError
from solver.sensors.inpe_cbers import CbersProduct, read_cbers
from solver.sensors.maxar import MaxarProduct, read_maxar
from solver.sensors.phr_dimap import is_phr_dimap, read_phr_dimap_root
from solver.sensors.xmlsafe import load, read_bytes

FORMATS = ("Maxar/DigitalGlobe support-data XML (root isd), DIMAP v1 of SPOT 1-5 (METADATA.DIM), DIMAP v2 "
           "of SPOT 6/7 and Pleiades (DIM_*.XML; root Dimap_Document), Pleiades ground-segment metadata "
           "(root PHR_Dimap_Document) or INPE product XML of CBERS-4/4A, Amazonia-1 (root prdf)")
Product = MaxarProduct | Spot5Product | DimapV2Product | CbersProduct
CAMERA_SUFFIXES = ("#left", "#right")
SUFFIX_WORDS = ("left", "right", "raw")  # after '#': a camera, and/or raw (INPE records)


def split_suffix(path: str | Path) -> tuple[Path, str | None, bool]:
    """``FILE#left``, ``FILE#raw``, ``FILE#right,raw`` -> (FILE, camera or None, raw); a name
    that exists as given, or whose suffix is not made of those words, is taken whole."""
    text = str(path)
    if "#" not in text or Path(text).exists():
        return Path(text), None, False
    base, _, suffix = text.rpartition("#")
    words = [w.strip() for w in suffix.split(",")]
    if not words or not all(w in SUFFIX_WORDS for w in words) or ("left" in words and "right" in words):
        return Path(text), None, False
    return Path(base), next((w for w in words if w != "raw"), None), "raw" in words


def read_product(path: str | Path, shown: str | None = None, data: bytes | str | None = None) -> Product:
    """The product of a metadata file (or of its bytes ``data``), by its root element
    (MetadataError naming the file when none of them)."""
    path, camera, raw = split_suffix(path)
    shown = str(path) if shown is None else shown
    if isinstance(data, str):
        data = data.encode()
    from_disk = data is None  # an upload's name is no path: nothing is looked for beside it
    if data is None:
        data = read_bytes(path, shown)
    if not data.strip():
        raise MetadataError(shown, "", f"empty ({len(data)} bytes): a metadata file expected ({FORMATS})")
    head = data[:4096]
    if b"<isd>" in head or b"<isd " in head:
        return read_maxar(path, shown, data)
    if b"<Dimap_Document" in head:
        root = load(path, shown, data)
        version = dimap_version(root)
        if version.startswith("1."):
            return read_dimap_v1_root(root, shown)
        if version.startswith("2."):
            return read_dimap_v2_root(root, path if from_disk else Path(""), shown)
        raise root.error(f"DIMAP version {version or 'unknown'}: 1.x (SPOT 1-5) or 2.x (SPOT 6/7, Pleiades) expected",
                         "Metadata_Identification/METADATA_FORMAT")
    if is_phr_dimap(head):
        return read_phr_dimap_root(load(path, shown, data), shown)
    if b"<prdf" in head:
        return read_cbers(path, shown, data, camera, raw_geometry=raw)
    raise MetadataError(shown, "", f"not a sensor metadata file we read: {FORMATS} expected")
