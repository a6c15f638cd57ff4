"""The readers of vendors' sensor metadata, registered (:data:`READERS`): the one list of the
formats ``pba import-sensor``, ``pba check-sensor``, the composition of uploaded files and the
web page's job builder (which learns the roots and file names from the server:
``GET /jobs/compose/formats``) know.

A reader says how its files are recognised (``detect`` on the first 4 kB, the XML ``roots`` and
usual ``file_names`` the builder uses), read (``read``: a product, or None when the file is
another reader's after all, e.g. another DIMAP version), and what its products give: the job
fragment's :class:`solver.sensors.job_fragment.SensorSource` (``source``) and the located
points the self-check compares with (``points``, :mod:`solver.sensors.self_check`). Those two
are named ``"module:function"`` and imported when first used: this module imports only the
vendors' readers, so the composition in the API process stays light and the fragment and the
self-check may look their reader up here.

A new vendor format is its module (reader, product, source and points functions) and one line
in :data:`READERS`.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Callable

from solver.sensors.dimap_spot5 import Spot5Product, dimap_version, read_dimap_v1_root
from solver.sensors.dimap_v2 import DimapV2Product, read_dimap_v2_root
from solver.sensors.inpe_cbers import CbersProduct, read_cbers
from solver.sensors.maxar import MaxarProduct, read_maxar
from solver.sensors.phr_dimap import is_phr_dimap, read_phr_dimap_root
from solver.sensors.xmlsafe import Node, load

HEAD_BYTES = 4096  # what ``detect`` sees of a file


@dataclass
class ReadRequest:
    """One file to read: its path (``FILE`` of ``FILE#left`` ...), the name shown in messages,
    its bytes, whether it is on disk (an upload's name is no path: nothing is looked for beside
    it), and the suffix words (``#left``/``#right``: the camera of a two-camera record; ``#raw``:
    measurements in the raw image)."""

    path: Path
    shown: str
    data: bytes
    from_disk: bool
    camera: str | None = None
    raw: bool = False

    @cached_property
    def root(self) -> Node:
        """The parsed XML (once, whichever reader asks)."""
        return load(self.path, self.shown, self.data)


@dataclass(frozen=True)
class Reader:
    """One format (module docstring)."""

    name: str
    description: str  # as the formats are listed in messages
    detect: Callable[[bytes], bool]
    read: Callable[[ReadRequest], Any]
    products: tuple[type, ...] = ()  # the product types whose source and points these are
    source: str | None = None  # "module:function": product -> SensorSource
    points: str | None = None  # "module:function": product -> (located points, notes)
    roots: tuple[str, ...] = ()  # XML root elements that name the format
    file_names: tuple[str, ...] = field(default_factory=tuple)  # file names that name the format alone (glob, any case)

    def source_of(self, product: Any) -> Any:
        return _function(self.source)(product)

    def points_of(self, product: Any) -> tuple[list[Any], list[str]]:
        return _function(self.points)(product) if self.points else ([], [])


def _function(ref: str | None) -> Callable[..., Any]:
    if ref is None:
        raise LookupError("the reader names no such function")
    module, _, name = ref.partition(":")
    return getattr(importlib.import_module(module), name)


def _has(*tags: bytes) -> Callable[[bytes], bool]:
    return lambda head: any(t in head for t in tags)


def _dimap_v1(req: ReadRequest) -> Spot5Product | None:
    return read_dimap_v1_root(req.root, req.shown) if dimap_version(req.root).startswith("1.") else None


def _dimap_v2(req: ReadRequest) -> DimapV2Product | None:
    version = dimap_version(req.root)
    if version.startswith("2."):
        return read_dimap_v2_root(req.root, req.path if req.from_disk else Path(""), req.shown)
    if version.startswith("1."):
        return None
    raise req.root.error(f"DIMAP version {version or 'unknown'}: 1.x (SPOT 1-5) or 2.x (SPOT 6/7, Pleiades) expected",
                         "Metadata_Identification/METADATA_FORMAT")


READERS: tuple[Reader, ...] = (
    Reader("maxar", "Maxar/DigitalGlobe support-data XML (root isd)", _has(b"<isd>", b"<isd "),
           lambda r: read_maxar(r.path, r.shown, r.data), (MaxarProduct,),
           "solver.sensors.job_fragment:maxar_source", "solver.sensors.self_check:maxar_points", ("isd",)),
    Reader("dimap-v1", "DIMAP v1 of SPOT 1-5 (METADATA.DIM)", _has(b"<Dimap_Document"), _dimap_v1, (Spot5Product,),
           "solver.sensors.job_fragment:spot5_source", "solver.sensors.self_check:spot5_points", ("Dimap_Document",), ("*.dim",)),
    Reader("dimap-v2", "DIMAP v2 of SPOT 6/7 and Pleiades (DIM_*.XML; root Dimap_Document)", _has(b"<Dimap_Document"), _dimap_v2,
           (DimapV2Product,), "solver.sensors.job_fragment:dimap_v2_source", "solver.sensors.self_check:dimap_v2_points",
           ("Dimap_Document",), ("dim_*.xml",)),
    Reader("phr-dimap", "Pleiades ground-segment metadata (root PHR_Dimap_Document)", is_phr_dimap,
           lambda r: read_phr_dimap_root(r.root, r.shown), roots=("PHR_Dimap_Document",)),
    Reader("inpe-cbers", "INPE product XML of CBERS-4/4A, Amazonia-1 (root prdf)", _has(b"<prdf"),
           lambda r: read_cbers(r.path, r.shown, r.data, r.camera, raw_geometry=r.raw), (CbersProduct,),
           "solver.sensors.job_fragment:cbers_source", "solver.sensors.self_check:cbers_points", ("prdf",)),
)


def formats_text() -> str:
    """The formats, listed for messages ("A, B or C")."""
    names = [r.description for r in READERS]
    return ", ".join(names[:-1]) + " or " + names[-1] if len(names) > 1 else "".join(names)


def reader_of(product: Any) -> Reader:
    """The registered reader whose products include ``product``'s type."""
    for reader in READERS:
        if isinstance(product, reader.products):
            return reader
    raise LookupError(f"no registered reader makes a {type(product).__name__}")


def describe() -> list[dict[str, Any]]:
    """The formats as the job builder learns them from the server: name, description, XML roots
    and usual file names."""
    return [{"name": r.name, "description": r.description, "roots": list(r.roots), "file_names": list(r.file_names)} for r in READERS]
