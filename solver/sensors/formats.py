"""Which reader a metadata file needs, by its root element: ``isd`` (Maxar support data,
:mod:`solver.sensors.maxar`), ``Dimap_Document`` (DIMAP v1 of SPOT 1-5,
:mod:`solver.sensors.dimap_spot5`; DIMAP v2 of SPOT 6/7 and Pleiades,
:mod:`solver.sensors.dimap_v2`, told apart by ``METADATA_FORMAT``'s version),
``PHR_Dimap_Document`` (Pleiades ground-segment metadata, :mod:`solver.sensors.phr_dimap`) or ``prdf`` (INPE
product XML of CBERS-4/4A and Amazonia-1: :mod:`solver.sensors.inpe_cbers`; ``FILE#left`` or
``FILE#right`` names the camera of a two-camera record, the left one by default)."""

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


def read_product(path: str | Path, shown: str | None = None, data: bytes | str | None = None) -> Product:
    """The product of a metadata file (or of its bytes ``data``), by its root element
    (MetadataError naming the file when none of them)."""
    camera = next((c[1:] for c in CAMERA_SUFFIXES if str(path).endswith(c) and not Path(path).exists()), None)
    path = Path(str(path)[: -len(camera) - 1]) if camera else Path(path)
    shown = str(path) if shown is None else shown
    if isinstance(data, str):
        data = data.encode()
    from_disk = data is None  # an upload's name is no path: nothing is looked for beside it
    if data is None:
        data = read_bytes(path, shown)
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
        return read_cbers(path, shown, data, camera)
    raise MetadataError(shown, "", f"not a sensor metadata file we read: {FORMATS} expected")
