"""The raster gate: every raster the solver and the server open or write goes through this module.

A raster is data, not a path GDAL may follow. Whoever opens a raster (the server's upload
check, the ``match`` process's worker, ``pba match``, the DEM and orthophoto readers, anything
later) calls :func:`open_raster` (or :func:`read_header`), and writes with :func:`create_raster`;
nothing else in ``solver/`` or ``service/`` calls ``rasterio.open`` or GDAL's open
(tests/test_raster_gate_call_sites.py lists the call sites). The gate:

- **opens only self-contained formats**: GDAL is handed an explicit driver list
  (:data:`DRIVERS`: GeoTIFF, JPEG 2000, NITF, PNG, JPEG), so a VRT, a GDAL XML service
  description or any format that names other files or URLs is "not a supported raster format"
  before its content is looked at;
- **opens plain local files only**: no ``/vsi*`` prefix, no URL, no GDAL connection string;
  the file must be a regular file (a FIFO, device, socket or directory is refused without
  being read; it is opened non-blocking, so a FIFO cannot stall the caller);
- **keeps to the caller's space** (:class:`RasterSpace`): on the server, the user's image
  folder (and the job's own upload folder). A name is checked as text first
  (:func:`check_name`: no NUL or control character, no over-long name or component, relative,
  no ``..``), then resolved with its links; a file whose real path leaves the space is refused
  with the same sentence whether or not it exists, and the file actually opened is checked
  again through ``/proc/self/fd`` (a link swapped in between is caught);
- **reads no sidecar and scans no directory**: GDAL never sees the file's folder. The gate
  opens the file itself and shows GDAL a private folder holding only a link to that open file
  (``/proc/self/fd/N``), plus the sidecars the caller asked for (an RPC's ``NAME_RPC.TXT`` or
  ``NAME.RPB``), each checked like the raster. So no ``.aux.xml``, ``.ovr``, ``.msk``, world
  file or ``OVERVIEW_FILE`` of anybody else is ever read; ``GDAL_DISABLE_READDIR_ON_OPEN`` and
  ``GDAL_PAM_ENABLED`` (:data:`FILE_OPTIONS`, around each open, and in the whole environment of
  a server process) say the same to GDAL;
- **keeps GDAL off the network in every process**: :func:`harden_gdal_environment` (run when
  this module is imported, and by the server, its workers and its GIS process at start) puts
  :data:`NETWORK_OPTIONS` in the environment, which child processes inherit:
  ``CPL_VSIL_CURL_ALLOWED_FILENAME`` names no file that can exist, so ``/vsicurl/`` and the
  cloud file systems built on it (``/vsis3/``, ``/vsigs/``, ``/vsiaz/`` ...) send nothing;
  ``PROJ_NETWORK=OFF`` keeps PROJ's grid downloads off;
- **bounds the work by header arithmetic** (:class:`RasterLimits`): sides, band-1 bytes
  (width x height x bytes per pixel) and the largest block GDAL would decode at once are
  checked from the header, before any pixel is read.

Refusals raise :class:`RasterRefused` (a ``code`` and a sentence naming the raster as the
caller showed it); the service turns them into 422 problems, the matching into its own errors.

Linux is assumed for the server (``/proc/self/fd``); elsewhere the gate opens the checked
real path (still with the driver list, no directory scan and the network off).
"""

from __future__ import annotations

import contextvars
import os
import shutil
import stat
import tempfile
import warnings
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

DRIVERS = ("GTiff", "JP2OpenJPEG", "NITF", "PNG", "JPEG")
"""GDAL drivers the gate opens: formats whose file holds its pixels and metadata itself."""
FORMATS = "GeoTIFF, JPEG 2000, NITF, PNG or JPEG"
"""The allowed formats as messages name them."""

NETWORK_OPTIONS = {
    # /vsicurl/ and every network file system built on it consider only this file to exist:
    # a name no URL can have, so nothing is ever requested (no HEAD, no GET)
    "CPL_VSIL_CURL_ALLOWED_FILENAME": "/pba-raster-gate/network-off",
    "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": ".pba-network-off",
    "CPL_CURL_ENABLE_VSIMEM": "NO",
    # whatever still reaches GDAL's HTTP client gives up at once
    "GDAL_HTTP_TIMEOUT": "1",
    "GDAL_HTTP_CONNECTTIMEOUT": "1",
    "GDAL_HTTP_MAX_RETRY": "0",
    "GDAL_HTTP_NETRC": "NO",
    "PROJ_NETWORK": "OFF",
}
"""GDAL (and PROJ) off the network: in the environment of every process that imports the gate."""
FILE_OPTIONS = {
    # no directory listing, no .aux.xml read or written, georeferencing from inside the file
    "GDAL_DISABLE_READDIR_ON_OPEN": "EMPTY_DIR",
    "GDAL_PAM_ENABLED": "NO",
    "GDAL_GEOREF_SOURCES": "INTERNAL",
}
"""GDAL reads no file beside a raster: set around every open of the gate, and in the whole
environment of a server process (:func:`lock_down_process`)."""
GDAL_OPTIONS = {**NETWORK_OPTIONS, **FILE_OPTIONS}
"""Every GDAL (and PROJ) option of the gate."""

MAX_NAME_BYTES = 1024  # a raster's name (relative path), UTF-8
MAX_COMPONENT_BYTES = 255  # one component of it (the file systems' NAME_MAX)
RPC_SIDECARS = ("{stem}_RPC.TXT", "{stem}_rpc.txt", "{stem}.RPB", "{stem}.rpb")
"""The RPC sidecars read beside a raster when a caller asks for them (GDAL's names)."""


class RasterRefused(ValueError):
    """The gate refuses a raster: ``code`` (``invalid_name``, ``outside_space``, ``not_found``,
    ``not_a_file``, ``unsupported_format``, ``unreadable``, ``too_large``) and a sentence naming
    the raster as the caller showed it (never a path outside the caller's space)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


@dataclass(frozen=True)
class RasterLimits:
    """Bounds checked on the header, before any pixel is decoded.

    ``max_side_px``: width and height; ``max_pixel_bytes``: band 1 decoded (width x height x
    bytes per pixel; None: no bound); ``max_block_bytes``: the largest block (strip or tile)
    GDAL decodes at once (a single-strip image of 16384 x 16384 pixels would be decoded whole
    by the first read)."""

    max_side_px: int = 1_000_000
    max_pixel_bytes: int | None = None
    max_block_bytes: int = 256 * 2**20


@dataclass(frozen=True)
class RasterSpace:
    """Where a caller's rasters may be.

    ``folders``: real paths of the folders the rasters must lie in (a name is resolved in the
    first); None means any local file (the command line: the user's own files, with the user's
    own permissions). ``limits`` bound every raster opened in this space."""

    folders: tuple[Path, ...] | None
    limits: RasterLimits = field(default_factory=RasterLimits)

    @classmethod
    def of(cls, *folders: str | os.PathLike[str], limits: RasterLimits | None = None) -> "RasterSpace":
        """A space of these folders (resolved now: a folder's own link is the server admin's)."""
        return cls(tuple(Path(os.path.realpath(f)) for f in folders), limits or RasterLimits())

    def contains(self, real: Path) -> bool:
        """Whether the real path ``real`` lies inside one of the folders (path components, not
        text: ``alice2/x.tif`` is not inside ``alice``)."""
        if self.folders is None:
            return True
        return any(real != f and real.is_relative_to(f) for f in self.folders)

    def resolve(self, name: str, shown: str | None = None) -> Path:
        """The real path of ``name`` (relative to the first folder; checked as text by
        :func:`check_name`); :class:`RasterRefused` when it is no regular file inside the space.
        The same sentence answers a path leaving the space whether its target exists or not."""
        shown = repr(name) if shown is None else shown
        if self.folders is None:
            return _checked_file(Path(os.path.realpath(name)), shown, self)
        if not self.folders:
            raise RasterRefused("outside_space", f"{shown}: no raster may be opened here")
        rel = check_name(name, shown)
        return _checked_file(Path(os.path.realpath(self.folders[0] / rel)), shown, self)


LOCAL = RasterSpace(None)
"""Any local file (the command line's space)."""
DENIED = RasterSpace(())
"""No file at all: a server process's space outside a job's (:func:`deny_by_default`)."""

_space: contextvars.ContextVar[RasterSpace | None] = contextvars.ContextVar("pba_raster_space", default=None)
_default_space = LOCAL


def current_space() -> RasterSpace:
    """The space of this context: the innermost :func:`confined`, else the process default
    (:data:`LOCAL`, or :data:`DENIED` after :func:`deny_by_default`)."""
    return _space.get() or _default_space


def deny_by_default() -> None:
    """From now on this process opens rasters only inside a :func:`confined` block (the server
    and its workers call it at start: a raster opened outside a job's space is refused)."""
    global _default_space
    _default_space = DENIED


def lock_down_process() -> None:
    """A server process (API, worker, GIS process): all the gate's GDAL options in its
    environment (also those against sidecars, for any GDAL use outside the gate) and no raster
    opened outside a :func:`confined` block or an explicit space."""
    harden_gdal_environment()
    os.environ.update(FILE_OPTIONS)
    deny_by_default()


@contextmanager
def confined(space: RasterSpace) -> Iterator[RasterSpace]:
    """Opens inside this block are held to ``space`` (a worker runs a job inside it)."""
    token = _space.set(space)
    try:
        yield space
    finally:
        _space.reset(token)


def harden_gdal_environment() -> None:
    """Put :data:`NETWORK_OPTIONS` in this process's environment (GDAL and PROJ read them at
    each use; child processes inherit them)."""
    os.environ.update(NETWORK_OPTIONS)


harden_gdal_environment()


def check_name(name: str, shown: str | None = None) -> PurePosixPath:
    """``name`` as a relative path inside a user's folder, checked as text before the file
    system sees it: :class:`RasterRefused` (``invalid_name``) for NUL and control characters,
    text that is not UTF-8, a name over :data:`MAX_NAME_BYTES` or a component over
    :data:`MAX_COMPONENT_BYTES` bytes, an absolute path, a drive, ``~``, a backslash, ``..``."""
    shown = repr(name[:80] + ("..." if len(name) > 80 else "")) if shown is None else shown
    if not isinstance(name, str) or not name:
        raise RasterRefused("invalid_name", f"{shown}: give the raster's path relative to your image folder")
    try:
        encoded = name.encode("utf-8")
    except UnicodeEncodeError:
        raise RasterRefused("invalid_name", f"{shown}: the name is not valid UTF-8 text") from None
    if any(c < 0x20 or c == 0x7F for c in encoded):
        raise RasterRefused("invalid_name", f"{shown}: the name holds a NUL or control character")
    if len(encoded) > MAX_NAME_BYTES:
        raise RasterRefused("invalid_name", f"{shown}: the name is longer than {MAX_NAME_BYTES} bytes")
    rel = PurePosixPath(name)
    if rel.is_absolute() or "\\" in name or name.startswith("~") or ":" in name[:3]:
        raise RasterRefused("invalid_name", f"{shown}: give a path relative to your image folder")
    if any(part == ".." for part in rel.parts):
        raise RasterRefused("invalid_name", f"{shown}: '..' is not allowed in image paths")
    if any(len(part.encode("utf-8")) > MAX_COMPONENT_BYTES for part in rel.parts):
        raise RasterRefused("invalid_name", f"{shown}: a component of the name is longer than {MAX_COMPONENT_BYTES} bytes")
    if not rel.parts:
        raise RasterRefused("invalid_name", f"{shown}: give the raster's path relative to your image folder")
    return rel


def _outside(shown: str) -> RasterRefused:
    return RasterRefused("outside_space", f"{shown} leads outside your image folder")


def _checked_file(real: Path, shown: str, space: RasterSpace) -> Path:
    if not space.contains(real):
        raise _outside(shown)
    try:
        st = os.stat(real)
    except (OSError, ValueError):
        raise RasterRefused("not_found", f"{shown}: no such raster in your image folder" if space.folders is not None
                            else f"{shown}: no such file") from None
    if not stat.S_ISREG(st.st_mode):
        raise RasterRefused("not_a_file", f"{shown}: not a regular file")
    return real


def _text_path(path: str | os.PathLike[str], shown: str) -> str:
    """A local path as text, refused when GDAL would read it as something else (a ``/vsi``
    prefix, a URL, a connection string or subdataset syntax, NUL)."""
    text = os.fspath(path)
    if not isinstance(text, str) or not text or "\0" in text:
        raise RasterRefused("invalid_name", f"{shown}: not a file name")
    low = text.lower()
    if low.startswith("/vsi") or "://" in low or (":" in text.split("/", 1)[0] and not Path(text).exists()):
        raise RasterRefused("invalid_name", f"{shown}: only plain local files are read (no /vsi, URL or GDAL connection string)")
    return text


def _open_fd(real: Path, shown: str, space: RasterSpace) -> int:
    """A read-only descriptor of the regular file ``real`` (non-blocking: a FIFO swapped in
    cannot stall), checked again after opening: the file opened is inside the space."""
    try:
        fd = os.open(real, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        raise RasterRefused("not_found", f"{shown}: cannot be opened (no such file, or a link was swapped in)") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise RasterRefused("not_a_file", f"{shown}: not a regular file")
        proc = Path(f"/proc/self/fd/{fd}")
        if proc.is_symlink():
            opened = Path(os.readlink(proc))
            if not space.contains(opened):
                raise _outside(shown)
        return fd
    except BaseException:
        os.close(fd)
        raise


@dataclass(frozen=True)
class RasterHeader:
    """What the header says: ``driver`` (GDAL's short name), ``width`` x ``height`` pixels,
    ``bands``, band 1's ``dtype`` and ``block`` (rows, columns of GDAL's natural block),
    ``has_rpc``, ``has_crs``."""

    driver: str
    width: int
    height: int
    bands: int
    dtype: str
    block: tuple[int, int]
    has_rpc: bool
    has_crs: bool
    data_end: int | None = None
    """Where the last block's bytes end in the file (GeoTIFF; None: not known from the header)."""

    @property
    def itemsize(self) -> int:
        import numpy as np

        return int(np.dtype(self.dtype).itemsize)

    @property
    def pixel_bytes(self) -> int:
        """Band 1 decoded (bytes)."""
        return self.width * self.height * self.itemsize

    @property
    def block_bytes(self) -> int:
        return self.block[0] * self.block[1] * self.itemsize


class GatedRaster:
    """A raster opened through the gate: ``dataset`` (rasterio, read-only), ``header``, ``path``
    (its real path), ``shown`` (the name messages give it). Close it (or use ``with``): its
    private folder and descriptors go with it."""

    def __init__(self, dataset: Any, header: RasterHeader, path: Path, shown: str, folder: str | None, fds: list[int]):
        self.dataset, self.header, self.path, self.shown = dataset, header, path, shown
        self._folder, self._fds = folder, fds
        self.gdal_name = dataset.name
        """The name GDAL knows the file by (the private link): for a GDAL option that must name
        this same raster (e.g. ``RPC_DEM``), never a path of the caller's."""

    def close(self) -> None:
        try:
            self.dataset.close()
        finally:
            for fd in self._fds:
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._fds = []
            if self._folder is not None:
                shutil.rmtree(self._folder, ignore_errors=True)
                self._folder = None

    def __enter__(self) -> "GatedRaster":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def message(self, text: str) -> str:
        """``text`` (a GDAL message) with the private names replaced by the raster's shown name."""
        if self._folder:
            text = text.replace(self.gdal_name, self.shown).replace(self._folder, "")
        return text


def _sidecars(real: Path, names: Iterable[str], space: RasterSpace) -> list[tuple[str, Path]]:
    """The sidecars of ``real`` named by ``names`` (``{stem}``, ``{name}`` formatted) that exist
    as regular files inside the space: (name, real path)."""
    out: list[tuple[str, Path]] = []
    seen: set[Path] = set()
    for pattern in names:
        name = pattern.format(stem=real.stem, name=real.name)
        if "/" in name or name in (".", ".."):
            continue
        candidate = Path(os.path.realpath(real.parent / name))
        if candidate in seen or not space.contains(candidate):
            continue
        try:
            if not stat.S_ISREG(os.stat(candidate).st_mode):
                continue
        except OSError:
            continue
        seen.add(candidate)
        out.append((name, candidate))
    return out


def _gdal_env() -> Any:
    import rasterio

    return rasterio.Env(**GDAL_OPTIONS)


def open_raster(
    path: str | os.PathLike[str],
    space: RasterSpace | None = None,
    *,
    shown: str | None = None,
    sidecars: Iterable[str] = (),
) -> GatedRaster:
    """Open the raster ``path`` (a real or absolute path; a user's relative name goes through
    :meth:`RasterSpace.resolve` first) read-only through the gate (module docstring), its
    header checked against the space's limits. ``sidecars``: names of files beside it GDAL may
    read (e.g. :data:`RPC_SIDECARS`), each held to the space like the raster.

    Raises :class:`RasterRefused`."""
    space = current_space() if space is None else space
    shown = str(path) if shown is None else shown
    text = _text_path(path, shown)
    if space.folders is not None and not space.folders:
        raise RasterRefused("outside_space", f"{shown}: no raster may be opened here")
    real = _checked_file(Path(os.path.realpath(text)), shown, space)
    fds = [_open_fd(real, shown, space)]
    folder: str | None = None
    try:
        if Path(f"/proc/self/fd/{fds[0]}").is_symlink():
            folder = tempfile.mkdtemp(prefix="pba-raster-")
            gdal_path = os.path.join(folder, real.name)
            os.symlink(f"/proc/self/fd/{fds[0]}", gdal_path)
            for name, side in _sidecars(real, sidecars, space):
                try:
                    fd = _open_fd(side, shown, space)
                except RasterRefused:
                    continue
                fds.append(fd)
                os.symlink(f"/proc/self/fd/{fd}", os.path.join(folder, name))
            readdir = "FALSE" if len(fds) > 1 else "EMPTY_DIR"  # the private folder: only what was chosen
        else:  # no /proc: the checked real path itself, no directory scan
            gdal_path, readdir = str(real), "EMPTY_DIR"
        dataset, header = _open_dataset(gdal_path, shown, folder, readdir)
        try:
            check_header(header, space.limits, shown)
            size = os.fstat(fds[0]).st_size
            if header.data_end is not None and header.data_end > size:
                raise RasterRefused("unreadable", f"{shown}: the file ends at byte {size}, before its last block (at "
                                    f"{header.data_end}): truncated")
        except BaseException:
            dataset.close()
            raise
        return GatedRaster(dataset, header, real, shown, folder, fds)
    except BaseException:
        for fd in fds:
            os.close(fd)
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
        raise


def _open_dataset(gdal_path: str, shown: str, folder: str | None, readdir: str) -> tuple[Any, RasterHeader]:
    """The dataset and its header, read while the gate's options hold (GDAL looks for a
    sidecar lazily, at the first metadata request: the header asks for the RPC here)."""
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.io import DatasetReader

    try:
        with _gdal_env(), rasterio.Env(GDAL_DISABLE_READDIR_ON_OPEN=readdir), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NotGeoreferencedWarning: raw image geometry
            ds = DatasetReader(gdal_path, driver=list(DRIVERS), sharing=False)  # rasterio.open takes one driver only
            try:
                header = _header(ds)
            except BaseException:
                ds.close()
                raise
    except RasterioError as exc:
        text = str(exc)
        if "not recognized as" in text or "not a supported" in text.lower():
            raise RasterRefused("unsupported_format", f"{shown}: not a supported raster format (the server reads {FORMATS})") from None
        if folder:
            text = text.replace(gdal_path, shown).replace(folder, "")
        raise RasterRefused("unreadable", f"{shown}: GDAL cannot read it as a raster (truncated or damaged?): {text}") from None
    if ds.driver not in DRIVERS:  # never: GDAL was given the list
        ds.close()
        raise RasterRefused("unsupported_format", f"{shown}: not a supported raster format (the server reads {FORMATS})")
    return ds, header


def _header(ds: Any) -> RasterHeader:
    block = tuple(int(v) for v in ds.block_shapes[0]) if ds.count else (0, 0)
    try:
        has_rpc = ds.rpcs is not None
    except (KeyError, ValueError):  # an incomplete RPC domain
        has_rpc = False
    return RasterHeader(ds.driver, int(ds.width), int(ds.height), int(ds.count), ds.dtypes[0] if ds.count else "",
                        (block[0], block[1]), has_rpc, ds.crs is not None, _tiff_data_end(ds, block))


def _tiff_data_end(ds: Any, block: tuple[int, ...]) -> int | None:
    """The end of the last block of the first and last bands of a GeoTIFF (from its strip or
    tile offsets and byte counts, read from the header; nothing is decoded)."""
    if ds.driver != "GTiff" or not ds.count or block[0] < 1 or block[1] < 1:
        return None
    last = f"{(ds.width - 1) // block[1]}_{(ds.height - 1) // block[0]}"
    ends = []
    for bidx in {1, ds.count}:
        try:
            offset = ds.get_tag_item(f"BLOCK_OFFSET_{last}", "TIFF", bidx=bidx)
            size = ds.get_tag_item(f"BLOCK_SIZE_{last}", "TIFF", bidx=bidx)
        except Exception:  # noqa: BLE001 - a header GDAL half-reads: no claim
            return None
        if offset is None or size is None:
            return None
        ends.append(int(offset) + int(size))
    return max(ends)


def check_header(header: RasterHeader, limits: RasterLimits, shown: str) -> None:
    """:class:`RasterRefused` (``too_large`` or ``unreadable``) when the header's arithmetic
    exceeds ``limits`` (nothing is decoded)."""
    if header.bands < 1:
        raise RasterRefused("unreadable", f"{shown}: the raster has no band")
    w, h = header.width, header.height
    if not (0 < w <= limits.max_side_px and 0 < h <= limits.max_side_px):
        raise RasterRefused("too_large", f"{shown}: the raster claims {w} x {h} pixels (1 to {limits.max_side_px} per side)")
    if limits.max_pixel_bytes is not None and header.pixel_bytes > limits.max_pixel_bytes:
        raise RasterRefused("too_large", f"{shown}: the raster claims {w} x {h} pixels of {header.dtype} ({header.pixel_bytes} bytes "
                            f"decoded), more than the {limits.max_pixel_bytes} bytes allowed here")
    if header.block_bytes > limits.max_block_bytes:
        raise RasterRefused("too_large", f"{shown}: the raster is stored in blocks of {header.block[1]} x {header.block[0]} pixels "
                            f"({header.block_bytes} bytes decoded at once; at most {limits.max_block_bytes}): re-tile it "
                            "(e.g. gdal_translate -co TILED=YES)")


def read_header(path: str | os.PathLike[str], space: RasterSpace | None = None, *, shown: str | None = None) -> RasterHeader:
    """The header of the raster ``path`` through the gate (:func:`open_raster`), checked
    against the space's limits; no pixel is read."""
    with open_raster(path, space, shown=shown) as r:
        return r.header


def create_raster(path: str | os.PathLike[str], **profile: Any) -> Any:
    """A new raster written at ``path`` (rasterio's writer, ``profile`` as ``rasterio.open(...,
    "w", ...)`` takes it), with the gate's GDAL options (no .aux.xml beside it, no network).
    Writing is for the caller's own outputs: the path is the caller's to choose."""
    import rasterio

    text = os.fspath(path)
    if text.lower().startswith("/vsi") or "://" in text:
        raise RasterRefused("invalid_name", f"{text}: rasters are written to plain local files only")
    with _gdal_env():
        return rasterio.open(text, "w", **profile)
