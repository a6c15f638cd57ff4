"""RPC export of one adjusted image: fit (:mod:`solver.gis.rpc_fit`) and write
(:mod:`solver.gis.rpc_io`) as a sidecar, an ``.RPB`` or the tags of a GeoTIFF copy.

An RPC image's (:mod:`solver.gis.rpc_image`) is its refined RPC: the adjusted bias folded into
the delivered RPC (no cross terms) or an RPC refitted to the adjusted model; it has one "chip"
(``"1"``), the whole image.

Per-chip RPCs (``per_chip``) map ground points to the columns of the chip's sub-image: the
delivered image's columns from the chip's first column inside the image (``first``), so the
sub-image's column 0 is the delivered image's column ``first`` (``fit["column_offset"]``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from solver.gis.model import AdjustedImage, AdjustedModel
from solver.gis.rpc_fit import HEIGHT_MARGIN_M, RPC, fit_image_rpc
from solver.gis.rpc_image import RpcImage, refined_rpc
from solver.gis.rpc_io import write_raster_with_rpc, write_sidecar


def height_range(model: AdjustedModel, dem_range_m: tuple[float, float] | None = None) -> tuple[float, float]:
    """Heights the fit grid spans: a DEM's range or the job's points', +- HEIGHT_MARGIN_M."""
    if dem_range_m is not None:
        return dem_range_m[0] - HEIGHT_MARGIN_M, dem_range_m[1] + HEIGHT_MARGIN_M
    return model.height_range_m(HEIGHT_MARGIN_M)


def image_rpcs(model: AdjustedModel, image: AdjustedImage | RpcImage, dem_range_m=None, per_chip: bool = False) -> list[RPC]:
    """The whole image's RPC, or one per chip (sub-image columns)."""
    hr = height_range(model, dem_range_m)
    if isinstance(image, RpcImage):
        rpc = refined_rpc(image, hr)
        if per_chip:
            rpc.fit["chip"] = "1"
        return [rpc]
    if not per_chip:
        return [fit_image_rpc(image, hr)]
    out = []
    for k in range(image.n_chips):
        rpc = fit_image_rpc(image, hr, chip=k)
        first = image.chip_range(k)[0]
        rpc = replace(rpc, samp_off=rpc.samp_off - first, fit={**rpc.fit, "column_offset": first})
        out.append(rpc)
    return out


def _chip_path(output: Path, chip: str) -> Path:
    name = output.name
    for tail in ("_RPC.TXT", "_rpc.txt", ".RPB", ".rpb", ".tif", ".tiff", ".TXT", ".txt"):
        if name.endswith(tail):
            return output.with_name(f"{name[: -len(tail)]}_{chip}{tail}")
    return output.with_name(f"{name}_{chip}")


def export_rpcs(
    model: AdjustedModel, image: AdjustedImage | RpcImage, output: Path, raster: Path | None = None, dem_range_m=None, per_chip: bool = False
) -> tuple[list[Path], list[dict[str, Any]]]:
    """Write the RPC(s) of ``image`` to ``output`` (format from its name); with ``raster`` a
    GeoTIFF copy with the RPC tags. Returns the paths written and the fit records."""
    output = Path(output)
    if raster is not None and output.suffix.lower() not in (".tif", ".tiff"):
        raise ValueError(f"--raster writes a GeoTIFF copy with RPC tags: -o must name a .tif, not {output.name!r}")
    if raster is not None and per_chip:
        raise ValueError("--raster and --per-chip together are not supported: write the per-chip sidecars beside the chips' sub-images")
    rpcs = image_rpcs(model, image, dem_range_m, per_chip)
    written = []
    for rpc in rpcs:
        path = _chip_path(output, rpc.fit["chip"]) if per_chip else output
        if raster is not None:
            written.append(write_raster_with_rpc(rpc, raster, path))
        else:
            written.append(write_sidecar(rpc, path))
    return written, [r.fit for r in rpcs]
