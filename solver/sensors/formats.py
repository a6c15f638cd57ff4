"""Which reader a metadata file needs: the first of the registered readers
(:data:`solver.sensors.readers.READERS`) that recognises it: today ``isd`` (Maxar support data,
:mod:`solver.sensors.maxar`), ``Dimap_Document`` (DIMAP v1 of SPOT 1-5,
:mod:`solver.sensors.dimap_spot5`; DIMAP v2 of SPOT 6/7 and Pleiades,
:mod:`solver.sensors.dimap_v2`, told apart by ``METADATA_FORMAT``'s version),
``PHR_Dimap_Document`` (Pleiades ground-segment metadata, :mod:`solver.sensors.phr_dimap`) or ``prdf`` (INPE
product XML of CBERS-4/4A and Amazonia-1: :mod:`solver.sensors.inpe_cbers`). ``FILE#left`` or
``FILE#right`` names the camera of a two-camera record, the left one by default, and ``#raw``
(``FILE#raw``, ``FILE#right,raw``) declares that the image measurements are in the raw image the
record describes, not in the map-projected raster INPE delivers."""

from __future__ import annotations

from pathlib import Path

from solver.sensors import readers
from solver.sensors.errors import MetadataError
from solver.sensors.readers import HEAD_BYTES, ReadRequest, formats_text
from solver.sensors.xmlsafe import read_bytes

FORMATS = formats_text()  # the registered readers (solver.sensors.readers) at import, listed for messages
Product = object  # a registered reader's product (solver.sensors.readers.READERS)
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
    """The product of a metadata file (or of its bytes ``data``), read by the first registered
    reader (:data:`solver.sensors.readers.READERS`) that recognises it and takes it
    (MetadataError naming the file when none of them)."""
    path, camera, raw = split_suffix(path)
    shown = str(path) if shown is None else shown
    if isinstance(data, str):
        data = data.encode()
    from_disk = data is None  # an upload's name is no path: nothing is looked for beside it
    if data is None:
        data = read_bytes(path, shown)
    if not data.strip():
        raise MetadataError(shown, "", f"empty ({len(data)} bytes): a metadata file expected ({formats_text()})")
    head = data[:HEAD_BYTES]
    request = ReadRequest(path, shown, data, from_disk, camera, raw)
    for reader in readers.READERS:
        if reader.detect(head):
            product = reader.read(request)
            if product is not None:
                return product
    raise MetadataError(shown, "", f"not a sensor metadata file we read: {formats_text()} expected")
