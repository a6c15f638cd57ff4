"""RPC00B files that GDAL reads: the ``_RPC.TXT`` sidecar, the ``.RPB`` file and GeoTIFF RPC tags.

Pixel convention. An RPC's image coordinates (``LINE_OFF``, ``SAMP_OFF`` and the polynomials)
put the **centre** of the top-left pixel at (0, 0), as the RPC00B specification and the solver do;
the files hold exactly what :class:`solver.gis.rpc_fit.RPC` holds. GDAL's RPC transformer
(``GDALCreateRPCTransformer``, rasterio's ``RPCTransformer``, ``gdalwarp -rpc``) works in GDAL's
raster convention, where (0, 0) is the top-left **corner** of the top-left pixel: it adds half
a pixel to what the polynomials give (a point at our (line, column) is at GDAL's
(line + 0.5, column + 0.5)). tests/solver/gis/test_gis_rpc.py checks this through GDAL itself.

GDAL finds a sidecar beside ``NAME.tif`` as ``NAME_RPC.TXT`` (or ``NAME_rpc.txt``) and
``NAME.RPB``.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from solver.gis.rpc_fit import RPC

_SCALARS = [
    ("ERR_BIAS", "err_bias", "meters", "errBias"), ("ERR_RAND", "err_rand", "meters", "errRand"),
    ("LINE_OFF", "line_off", "pixels", "lineOffset"), ("SAMP_OFF", "samp_off", "pixels", "sampOffset"),
    ("LAT_OFF", "lat_off", "degrees", "latOffset"), ("LONG_OFF", "long_off", "degrees", "longOffset"),
    ("HEIGHT_OFF", "height_off", "meters", "heightOffset"),
    ("LINE_SCALE", "line_scale", "pixels", "lineScale"), ("SAMP_SCALE", "samp_scale", "pixels", "sampScale"),
    ("LAT_SCALE", "lat_scale", "degrees", "latScale"), ("LONG_SCALE", "long_scale", "degrees", "longScale"),
    ("HEIGHT_SCALE", "height_scale", "meters", "heightScale"),
]
_COEFFS = [
    ("LINE_NUM_COEFF", "line_num", "lineNumCoef"), ("LINE_DEN_COEFF", "line_den", "lineDenCoef"),
    ("SAMP_NUM_COEFF", "samp_num", "sampNumCoef"), ("SAMP_DEN_COEFF", "samp_den", "sampDenCoef"),
]
FORMATS = ("txt", "rpb")


def rpc_txt(rpc: RPC) -> str:
    """GDAL's RPC text format (what GDAL writes as ``NAME_RPC.TXT``): ``KEY: value unit`` lines,
    the coefficients as ``LINE_NUM_COEFF_1`` .. ``_20``."""
    out = []
    for key, attr, unit, _ in _SCALARS:
        out.append(f"{key}: {getattr(rpc, attr):+.15e} {unit}")
    for key, attr, _ in _COEFFS:
        for i, v in enumerate(getattr(rpc, attr), start=1):
            out.append(f"{key}_{i}: {v:+.15e}")
    return "\n".join(out) + "\n"


def rpc_rpb(rpc: RPC, sat_id: str = "PBA", band_id: str = "P") -> str:
    """The ``.RPB`` format (DigitalGlobe style; GDAL reads it beside ``NAME.tif`` as ``NAME.RPB``)."""
    out = [f'satId = "{sat_id}";', f'bandId = "{band_id}";', 'SpecId = "RPC00B";', "BEGIN_GROUP = IMAGE"]
    for _, attr, _, name in _SCALARS:
        out.append(f"\t{name} = {getattr(rpc, attr):+.15e};")
    for _, attr, name in _COEFFS:
        vals = getattr(rpc, attr)
        out.append(f"\t{name} = (")
        out += [f"\t\t\t{v:+.15e}," for v in vals[:-1]]
        out.append(f"\t\t\t{vals[-1]:+.15e});")
    out += ["END_GROUP = IMAGE", "END;"]
    return "\n".join(out) + "\n"


def render(rpc: RPC, fmt: str) -> str:
    """The RPC as text in ``fmt`` (``txt``: GDAL's _RPC.TXT, ``rpb``: .RPB)."""
    if fmt == "txt":
        return rpc_txt(rpc)
    if fmt == "rpb":
        return rpc_rpb(rpc)
    raise ValueError(f"unknown RPC format {fmt!r} (one of {', '.join(FORMATS)})")


def read_rpc_txt(text: str) -> RPC:
    """Parse GDAL's RPC text format (inverse of :func:`rpc_txt`)."""
    md: dict[str, str] = {}
    coeff: dict[str, list[tuple[int, float]]] = {}
    for row in text.splitlines():
        if ":" not in row:
            continue
        key, value = (x.strip() for x in row.split(":", 1))
        head, _, idx = key.rpartition("_")
        if head.endswith("_COEFF") and idx.isdigit():
            coeff.setdefault(head, []).append((int(idx), float(value.split()[0])))
        else:
            md[key] = value
    for key, items in coeff.items():
        md[key] = " ".join(str(v) for _, v in sorted(items))
    return RPC.from_gdal(md)


def write_sidecar(rpc: RPC, path: Path) -> Path:
    """Write ``path`` in the format its name says (``*_RPC.TXT``/``.txt``: text, ``.RPB``)."""
    path = Path(path)
    fmt = "rpb" if path.suffix.lower() == ".rpb" else "txt"
    path.write_text(render(rpc, fmt))
    return path


def write_raster_with_rpc(rpc: RPC, source: Path, destination: Path) -> Path:
    """A GeoTIFF copy of ``source`` with the RPC as GeoTIFF RPC tags (rasterio / GDAL)."""
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.rpc import RPC as GdalRPC

    from solver.raster_gate import create_raster, open_raster

    with open_raster(source) as gated:
        src = gated.dataset
        profile = src.profile.copy()
        profile.update(driver="GTiff")
        profile.pop("crs", None)
        profile.pop("transform", None)
        data = src.read()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # raw image geometry: the RPC is its georeferencing
        with create_raster(destination, **profile) as dst:
            dst.write(data)
            dst.rpcs = GdalRPC.from_gdal(rpc.to_gdal())
    return Path(destination)


def gdal_rpc(rpc: RPC):
    """The same RPC as rasterio's :class:`rasterio.rpc.RPC` (for GDAL's transformer and warper)."""
    from rasterio.rpc import RPC as GdalRPC

    return GdalRPC.from_gdal(rpc.to_gdal())


def gdal_ground_to_image(rpc_gdal, lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GDAL's RPC transformer, ground to image, in GDAL's pixel-corner convention (line, column)."""
    from rasterio.transform import RPCTransformer

    with RPCTransformer(rpc_gdal) as tr:
        rows, cols = tr.rowcol(np.asarray(lon, float), np.asarray(lat, float), zs=np.asarray(h, float), op=lambda x: x)
    return np.asarray(rows, float), np.asarray(cols, float)
