"""The DEM test data and the shipped geoid grid, from a checkout of CNES shareloc (Apache-2.0;
tests/data/dem/README.md names the commit).

    python scripts/shareloc_dem_data.py SHARELOC_DIR

- ``tests/data/dem/srtm_ventoux.tif``: the window of shareloc's SRTM 3-arc-second tile
  N44E005 (``tests/data/dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt``) around the
  Mont Ventoux crops of tests/data/matching; the heights (EGM96, int16 metres), the CRS
  (EPSG:4326, no vertical part, as the tile) and no-data value unchanged, deflate.
- ``solver/geometry/data/us_nga_egm96_15.tif``: shareloc's ``tests/data/dtm/geoid/egm96_15.gtx``
  (NGA's EGM96 15-minute undulations) as a GeoTIFF of the same float32 values under PROJ's
  name for it, with the metadata PROJ reads from its vertical grids; deflate, lossless.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WINDOW_DEG = (5.16, 44.18, 5.23, 44.23)  # west, south, east, north: the Ventoux crops with a few km around


def srtm_crop(shareloc: Path, out: Path) -> None:
    import rasterio
    from rasterio.windows import from_bounds

    with rasterio.open(shareloc / "tests/data/dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt") as src:
        win = from_bounds(*WINDOW_DEG, src.transform).round_offsets().round_lengths()
        values = src.read(1, window=win)
        profile = dict(driver="GTiff", dtype=values.dtype, width=values.shape[1], height=values.shape[0], count=1,
                       crs=src.crs, transform=src.window_transform(win), nodata=src.nodata, compress="deflate")
    out.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(values, 1)


def geoid_grid(shareloc: Path, out: Path) -> None:
    import rasterio

    with rasterio.open(shareloc / "tests/data/dtm/geoid/egm96_15.gtx") as src:
        values = src.read(1).astype(np.float32)
        profile = dict(driver="GTiff", dtype="float32", width=src.width, height=src.height, count=1, crs="EPSG:4326",
                       transform=src.transform, compress="deflate", predictor=3, zlevel=9, tiled=True,
                       blockxsize=256, blockysize=256)
    out.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(values, 1)
        dst.update_tags(TYPE="VERTICAL_OFFSET_GEOGRAPHIC_TO_VERTICAL", area_of_use="World",
                        source="NGA EGM96 15-minute geoid undulations (public domain), via CNES shareloc egm96_15.gtx")
        dst.set_band_description(1, "geoid_undulation")
        dst.units = ("metre",)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shareloc", type=Path)
    args = parser.parse_args()
    srtm_crop(args.shareloc, ROOT / "tests/data/dem/srtm_ventoux.tif")
    geoid_grid(args.shareloc, ROOT / "solver/geometry/data/us_nga_egm96_15.tif")


if __name__ == "__main__":
    main()
