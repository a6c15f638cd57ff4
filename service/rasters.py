"""The rasters of the ``match`` process: files already on the server under ``PBA_IMAGE_ROOT``
(one subfolder per user name) and bounded uploads.

A request names a server raster by its path inside the caller's subfolder. The path must be
relative, without ``..``, and must resolve (symbolic links followed) to a regular file inside
that subfolder: a link that leaves it, an absolute path or a parent reference is refused
(422, pointing at the input), as is a user name that cannot be a folder name. The check runs
when the job is submitted and again in the worker just before reading (a link changed in
between is caught there).

An upload is the file's bytes in base64 (``inputs.images[].value``), at most
``PBA_MAX_IMAGE_UPLOAD_BYTES`` decoded, opened by GDAL from memory at submission (a file GDAL
cannot read, or of an absurd size, is a 422 then); the worker writes it to a temporary
directory for the matching and deletes it afterwards.
"""

from __future__ import annotations

import base64
import binascii
import os
import re
from pathlib import Path, PurePosixPath
from typing import Any

from service.errors import InvalidInput

USER_FOLDER = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
MAX_SIDE_PX = 1_000_000  # the matching's own bound (solver.matching.raster), checked early
MAX_UPLOAD_PIXEL_BYTES = 512 * 1024 * 1024  # an upload's band 1 decompressed (a small file may claim a huge image)


def _refuse(index: int, field: str, code: str, message: str) -> InvalidInput:
    return InvalidInput(message, [{"pointer": f"/inputs/images/{index}/{field}", "code": code, "message": message}])


def user_folder(root: Path, user_name: str) -> Path:
    """The caller's folder under the image root (resolved; it need not exist)."""
    if not USER_FOLDER.fullmatch(user_name) or user_name in (".", ".."):
        raise ValueError(f"user name {user_name!r} cannot name a folder")
    return Path(os.path.realpath(root)) / user_name


def resolve(root: Path | None, user_name: str, relative: str, index: int) -> Path:
    """The real path of the server raster ``relative`` of ``user_name``; InvalidInput (pointer
    ``/inputs/images/{index}/path``) when it is not a file inside the user's folder."""
    if root is None:
        raise _refuse(index, "path", "no_image_root", "this server has no image root (PBA_IMAGE_ROOT): upload the raster instead")
    rel = PurePosixPath(relative)
    if rel.is_absolute() or "\\" in relative or relative.startswith("~") or ":" in relative[:3]:
        raise _refuse(index, "path", "outside_image_root", f"{relative!r}: give a path relative to your image folder")
    if any(part == ".." for part in rel.parts):
        raise _refuse(index, "path", "outside_image_root", f"{relative!r}: '..' is not allowed in image paths")
    try:
        folder = user_folder(root, user_name)
    except ValueError as exc:
        raise _refuse(index, "path", "no_image_folder", str(exc)) from None
    real = Path(os.path.realpath(folder / rel))
    if real != folder and folder not in real.parents:
        raise _refuse(index, "path", "outside_image_root", f"{relative!r} leads outside your image folder")
    if not real.is_file():
        raise _refuse(index, "path", "not_found", f"{relative!r}: no such raster in your image folder")
    return real


def decode_upload(value: str, limit_bytes: int, index: int) -> bytes:
    """The uploaded raster's bytes; InvalidInput (pointer ``/inputs/images/{index}/value``)
    for bad base64, a file over ``limit_bytes`` or one GDAL cannot read or that claims an
    absurd size."""
    if len(value) > 4 * (limit_bytes // 3 + 1) + 4:
        raise _refuse(index, "value", "too_large", f"the upload is larger than {limit_bytes} bytes (PBA_MAX_IMAGE_UPLOAD_BYTES); put large rasters under the server's image root")
    try:
        data = base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise _refuse(index, "value", "invalid_base64", "the upload is not valid base64") from None
    if len(data) > limit_bytes:
        raise _refuse(index, "value", "too_large", f"the upload is larger than {limit_bytes} bytes (PBA_MAX_IMAGE_UPLOAD_BYTES)")
    _check_raster(data, index)
    return data


def _check_raster(data: bytes, index: int) -> None:
    """GDAL opens ``data`` and reads every pixel of band 1 (a truncated file fails here)."""
    import warnings

    import numpy as np
    from rasterio.errors import RasterioError
    from rasterio.io import MemoryFile

    try:
        with warnings.catch_warnings(), MemoryFile(data) as mem, mem.open() as ds:
            warnings.simplefilter("ignore")
            if ds.count < 1:
                raise _refuse(index, "value", "unreadable_raster", "the uploaded raster has no band")
            w, h = ds.width, ds.height
            if not (0 < w <= MAX_SIDE_PX and 0 < h <= MAX_SIDE_PX) or w * h * np.dtype(ds.dtypes[0]).itemsize > MAX_UPLOAD_PIXEL_BYTES:
                raise _refuse(index, "value", "absurd_size",
                              f"the uploaded raster claims {w} x {h} pixels: too large for an upload (put it under the server's image root)")
            ds.read(1)
    except (RasterioError, OSError, ValueError, TypeError) as exc:
        raise _refuse(index, "value", "unreadable_raster", f"GDAL cannot read the upload as a raster (truncated or not a raster?): {exc}") from None


def stored_rasters(images: list[Any], root: Path | None, user_name: str, limit_bytes: int) -> list[dict[str, Any]]:
    """The rasters as the job document stores them: ``{"id", "path"}`` (relative, checked) or
    ``{"id", "upload"}`` (base64, checked); ids distinct."""
    seen: set[str] = set()
    out = []
    for k, im in enumerate(images):
        if im.id in seen:
            raise _refuse(k, "id", "duplicate", f"image {im.id!r} is given twice")
        seen.add(im.id)
        if im.path is not None:
            resolve(root, user_name, im.path, k)
            out.append({"id": im.id, "path": im.path})
        else:
            decode_upload(im.value, limit_bytes, k)
            out.append({"id": im.id, "upload": im.value})
    return out
