"""The rasters of the ``match`` process: files already on the server under ``PBA_IMAGE_ROOT``
(one subfolder per user name) and bounded uploads, all through the raster gate
(:mod:`solver.raster_gate`; docs/server-limits.md).

A request names a server raster by its path inside the caller's subfolder. The name is checked
as text first (no NUL or control character, not over-long, relative, no ``..``), then it must
resolve (links followed) to a regular file inside that subfolder: a link that leaves it is
refused (422, pointing at the input) with the same sentence whether its target exists or not,
as is a user name that cannot be a folder name. The check runs when the job is submitted and
again in the worker, which opens the file through the gate inside the job's space only (a link
changed in between is caught there).

An upload is the file's bytes in base64 (``inputs.images[].value``), at most
``PBA_MAX_IMAGE_UPLOAD_BYTES`` decoded; the worker writes it to a temporary folder of its own
for the matching and deletes it afterwards.

At submission only the header of each raster is read (no pixel is decoded): an allowed format,
its size and pixel type against the limits (``PBA_MAX_UPLOAD_PIXEL_BYTES`` for uploads,
``PBA_MAX_RASTER_PIXEL_BYTES`` for the image root: width x height x bytes per pixel of band 1)
and against the size the job states for the image.
"""

from __future__ import annotations

import base64
import binascii
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable

from service.errors import InvalidInput
from solver.raster_gate import RasterHeader, RasterLimits, RasterRefused, RasterSpace, open_raster

USER_FOLDER = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
MAX_SIDE_PX = 1_000_000  # the matching's own bound (solver.matching.raster), checked early
UPLOAD_NAME = "upload.raster"  # the name an upload is checked under (its own name is never used)


def _refuse(index: int, field: str, code: str, message: str) -> InvalidInput:
    return InvalidInput(message, [{"pointer": f"/inputs/images/{index}/{field}", "code": code, "message": message}])


def user_folder(root: Path, user_name: str) -> Path:
    """The caller's folder under the image root (resolved; it need not exist)."""
    if not USER_FOLDER.fullmatch(user_name) or user_name in (".", ".."):
        raise ValueError(f"user name {user_name!r} cannot name a folder")
    return Path(os.path.realpath(root)) / user_name


def image_space(root: Path, user_name: str, max_pixel_bytes: int | None = None) -> RasterSpace:
    """The raster gate's space of ``user_name``'s image folder (ValueError for a user name that
    cannot be a folder)."""
    return RasterSpace((user_folder(root, user_name),), RasterLimits(MAX_SIDE_PX, max_pixel_bytes))


def resolve(root: Path | None, user_name: str, relative: str, index: int) -> Path:
    """The real path of the server raster ``relative`` of ``user_name``; InvalidInput (pointer
    ``/inputs/images/{index}/path``) when it is not a regular file inside the user's folder."""
    if root is None:
        raise _refuse(index, "path", "no_image_root", "this server has no image root (PBA_IMAGE_ROOT): upload the raster instead")
    try:
        space = image_space(root, user_name)
    except ValueError as exc:
        raise _refuse(index, "path", "no_image_folder", str(exc)) from None
    try:
        return space.resolve(relative, shown=repr(relative[:200]))
    except RasterRefused as exc:
        raise _refuse(index, "path", exc.code, exc.message) from None


def check_path_header(root: Path | None, user_name: str, relative: str, index: int, max_pixel_bytes: int) -> RasterHeader:
    """The header of the server raster ``relative`` (resolved as :func:`resolve` does) read
    through the gate and checked against ``max_pixel_bytes``; InvalidInput otherwise."""
    real = resolve(root, user_name, relative, index)
    assert root is not None  # resolve refuses a server without an image root
    space = image_space(root, user_name, max_pixel_bytes)
    try:
        with open_raster(real, space, shown=repr(relative[:200])) as gated:
            return gated.header
    except RasterRefused as exc:
        raise _refuse(index, "path", exc.code, exc.message) from None


def decode_upload(value: str, limit_bytes: int, index: int) -> bytes:
    """The uploaded raster's bytes; InvalidInput (pointer ``/inputs/images/{index}/value``)
    for bad base64 or a file over ``limit_bytes``."""
    if len(value) > 4 * (limit_bytes // 3 + 1) + 4:
        raise _refuse(index, "value", "too_large", f"the upload is larger than {limit_bytes} bytes (PBA_MAX_IMAGE_UPLOAD_BYTES); put large rasters under the server's image root")
    try:
        data = base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise _refuse(index, "value", "invalid_base64", "the upload is not valid base64") from None
    if len(data) > limit_bytes:
        raise _refuse(index, "value", "too_large", f"the upload is larger than {limit_bytes} bytes (PBA_MAX_IMAGE_UPLOAD_BYTES)")
    return data


def check_upload_header(data: bytes, index: int, max_pixel_bytes: int) -> RasterHeader:
    """The header of an uploaded raster, read through the gate from a private temporary folder
    (no pixel is decoded) and checked against ``max_pixel_bytes``; InvalidInput otherwise."""
    folder = tempfile.mkdtemp(prefix="pba-upload-")
    try:
        path = Path(folder) / UPLOAD_NAME
        path.write_bytes(data)
        space = RasterSpace((Path(os.path.realpath(folder)),), RasterLimits(MAX_SIDE_PX, max_pixel_bytes))
        try:
            with open_raster(os.path.realpath(path), space, shown="the upload") as gated:
                return gated.header
        except RasterRefused as exc:
            raise _refuse(index, "value", exc.code, exc.message) from None
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def stated_sizes(job: Any) -> dict[str, tuple[int | None, int | None]]:
    """The image size (lines, columns) the job states for each image: its camera's, where the
    camera gives them (an RPC image states none)."""
    cameras = {c.id: c for c in job.cameras}
    out: dict[str, tuple[int | None, int | None]] = {}
    for im in job.images:
        cam = cameras.get(im.camera) if isinstance(im.camera, str) else None
        out[im.id] = (getattr(cam, "lines", None), getattr(cam, "columns", None))
    return out


def _check_size(header: RasterHeader, image_id: str, stated: tuple[int | None, int | None], index: int, field: str) -> None:
    """The job's stated image size against the header's."""
    lines, columns = stated
    for what, want, have in (("lines", lines, header.height), ("columns", columns, header.width)):
        if want is not None and have != want:
            message = f"the raster has {header.height} lines x {header.width} columns; image {image_id!r} of the job has {want} {what}"
            raise _refuse(index, field, "size_mismatch", message)


def _inline(_pointer: str, _shown: str, name: str, *args: Any) -> Any:
    return globals()[name](*args)


def stored_rasters(images: list[Any], root: Path | None, user_name: str, limit_bytes: int,
                   max_upload_pixel_bytes: int, max_raster_pixel_bytes: int,
                   sizes: dict[str, tuple[int | None, int | None]] | None = None,
                   run: Callable[..., Any] | None = None) -> list[dict[str, Any]]:
    """The rasters as the job document stores them: ``{"id", "path", "pixels"}`` (relative,
    checked) or ``{"id", "upload", "pixels"}`` (base64, checked); ids distinct. ``pixels``: the
    header's width x height (what the matching will cost).

    ``run(pointer, shown, name, *args)``: how a header check (``check_path_header`` or
    ``check_upload_header`` of this module) runs: here by default; the API hands it to its
    check processes (service.raster_checks), ``pointer`` and ``shown`` naming the raster if
    the check fails there."""
    run = run or _inline
    seen: set[str] = set()
    out = []
    for k, im in enumerate(images):
        if im.id in seen:
            raise _refuse(k, "id", "duplicate", f"image {im.id!r} is given twice")
        seen.add(im.id)
        if im.path is not None:
            header = run(f"/inputs/images/{k}/path", repr(im.path[:200]), "check_path_header",
                         root, user_name, im.path, k, max_raster_pixel_bytes)
            entry = {"id": im.id, "path": im.path}
            field = "path"
        else:
            header = run(f"/inputs/images/{k}/value", "the upload", "check_upload_header",
                         decode_upload(im.value, limit_bytes, k), k, max_upload_pixel_bytes)
            entry = {"id": im.id, "upload": im.value}
            field = "value"
        if sizes is not None and im.id in sizes:
            _check_size(header, im.id, sizes[im.id], k, field)
        out.append({**entry, "pixels": header.width * header.height})
    return out
