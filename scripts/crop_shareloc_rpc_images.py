"""Real Pleiades crops with their RPCs for the matching tests (tests/data/matching/), from a
checkout of CNES shareloc (Apache-2.0; tests/data/matching/README.md names the commit).

    python scripts/crop_shareloc_rpc_images.py SHARELOC_DIR tests/data/matching

shareloc's test images are crops of Pleiades 1B primary scenes: each GeoTIFF's geotransform
holds the crop's origin in the scene (columns, rows; scale 1), and an OSSIM ``.geom`` file the
scene's RPC00B (0-based, pixel centres: the convention of our RPCs). A crop's RPC is the
scene's with ``LINE_OFF`` and ``SAMP_OFF`` moved by the crop's origin; it is written as GDAL's
``NAME_RPC.TXT`` sidecar. Pixels are the original digital numbers (integers, stored as
uint16, deflate): only the window changes.
"""

from __future__ import annotations

import argparse
import dataclasses
import warnings
from pathlib import Path

import numpy as np

# (output name, shareloc image, shareloc .geom, window (row, column, rows, columns) or None: whole)
CROPS = [
    ("ventoux_left", "tests/data/image/phr_ventoux/left_image.tif", "tests/data/rpc/phr_ventoux/left_image.geom", None),
    ("ventoux_right", "tests/data/image/phr_ventoux/right_image.tif", "tests/data/rpc/phr_ventoux/right_image.geom", None),
    ("gizeh_img1", "tests/data/image/phr_gizeh/img1.tif", "tests/data/rpc/phr_gizeh/img1.geom", (200, 200, 400, 400)),
    ("gizeh_img2", "tests/data/image/phr_gizeh/img2.tif", "tests/data/rpc/phr_gizeh/img2.geom", (200, 200, 400, 400)),
]


def read_geom(path: Path):
    """The RPC00B of an OSSIM ``.geom`` keyword list (``key: value`` lines, coefficients
    ``line_num_coeff_00`` .. ``_19``)."""
    from solver.gis.rpc_fit import RPC

    kw: dict[str, str] = {}
    for row in path.read_text().splitlines():
        if ":" in row:
            key, value = row.split(":", 1)
            kw[key.strip()] = value.strip()

    def coeffs(name: str) -> np.ndarray:
        return np.array([float(kw[f"{name}_{i:02d}"]) for i in range(20)])

    scalars = ("line_off", "samp_off", "lat_off", "long_off", "height_off", "line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale")
    return RPC(*(float(kw[k]) for k in scalars), coeffs("line_num_coeff"), coeffs("line_den_coeff"), coeffs("samp_num_coeff"), coeffs("samp_den_coeff"))


def crop(source: Path, geom: Path, window: tuple[int, int, int, int] | None, out_tif: Path) -> None:
    """Write ``out_tif`` (uint16, deflate) and its ``_RPC.TXT`` sidecar."""
    import rasterio
    import rasterio.errors

    from solver.gis.rpc_io import write_sidecar

    with rasterio.open(source) as src:
        t = src.transform
        if (t.a, t.b, t.d, t.e) != (1.0, 0.0, 0.0, 1.0):
            raise SystemExit(f"{source}: the geotransform is not a crop origin with scale 1 ({t})")
        data = src.read(1)
    row0, col0 = t.f, t.c
    if window is not None:
        r, c, h, w = window
        data = data[r:r + h, c:c + w]
        row0, col0 = row0 + r, col0 + c
    if not np.array_equal(data, np.round(data)) or data.min() < 0 or data.max() > 65535:
        raise SystemExit(f"{source}: pixels are not 16-bit digital numbers")
    rpc = read_geom(geom)
    rpc = dataclasses.replace(rpc, line_off=rpc.line_off - row0, samp_off=rpc.samp_off - col0)
    warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)  # raw image geometry: no geotransform
    with rasterio.open(out_tif, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype="uint16",
                       compress="deflate", predictor=2) as dst:
        dst.write(data.astype(np.uint16), 1)
    write_sidecar(rpc, out_tif.with_name(out_tif.stem + "_RPC.TXT"))
    print(f"{out_tif}: {data.shape[0]} x {data.shape[1]} px from scene row {row0:g}, column {col0:g}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shareloc", type=Path, help="a checkout of https://github.com/CNES/shareloc")
    ap.add_argument("output", type=Path, help="output directory")
    args = ap.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    for name, image, geom, window in CROPS:
        crop(args.shareloc / image, args.shareloc / geom, window, args.output / f"{name}.tif")


if __name__ == "__main__":
    main()
