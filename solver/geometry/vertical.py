"""Vertical datums of DEM heights: ellipsoidal (WGS 84) or above a geoid (EGM96, EGM2008, any
vertical CRS PROJ knows), converted to the ellipsoidal heights the adjustment uses.

SRTM and Copernicus DEM give heights above a geoid (EGM96 and EGM2008); the difference to
ellipsoidal heights (the undulation N, ``h = H + N``) reaches -106 to +85 m worldwide, so a
height taken in the wrong datum is tens of metres off. The datum is never assumed: it comes
from the raster's CRS (a compound CRS with a vertical part, or a 3D geographic CRS, whose
heights are ellipsoidal) or from the caller (``--dem-vertical``); a raster that states neither
is refused with the choices. When the file and the caller disagree, the caller's choice is
refused too (one of them is wrong, and we cannot tell which).

The conversion is PROJ's (pyproj), with the network off: the geoid grid must be on this
machine. EGM96 (15', the grid of SRTM) is shipped with the solver (``solver/geometry/data``,
public-domain NGA data; added to PROJ's search path here); other grids (EGM2008's
``us_nga_egm08_25.tif``, 77 MB) are looked up where PROJ looks (its data directories, the
user's PROJ directory, ``PROJ_DATA``). A grid that is missing is an error naming the grid and
where to put it, never a silent fall back to PROJ's "ballpark" (no-op) transformation.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError, ProjError

DATA_DIR = Path(__file__).resolve().parent / "data"
"""Grids shipped with the solver (added to PROJ's search path by :func:`_proj_search_path`)."""

ELLIPSOIDAL = "ellipsoid"
NAMES = {"egm96": "EPSG:5773", "egm2008": "EPSG:3855"}
"""Short names of ``--dem-vertical`` besides ``ellipsoid`` and any vertical CRS PROJ parses."""

CHOICES = "ellipsoid (WGS 84 heights), egm96 (SRTM), egm2008 (Copernicus DEM) or a vertical CRS such as EPSG:5773"


class VerticalDatumError(ValueError):
    """A DEM's vertical datum is unknown, contradictory, or cannot be converted offline."""


@dataclass(frozen=True)
class VerticalDatum:
    """How a DEM's heights relate to the WGS 84 ellipsoid.

    ``crs``: the vertical CRS (None: the heights are ellipsoidal); ``name``: its name for the
    report; ``source``: where it was read ("the file's CRS" or the caller's flag)."""

    crs: CRS | None
    name: str
    source: str

    @property
    def ellipsoidal(self) -> bool:
        return self.crs is None

    def to_dict(self) -> dict[str, str | None]:
        code = None if self.crs is None else _code(self.crs)
        return {"name": self.name, "crs": code, "source": self.source}

    def undulation(self, lon_deg: np.ndarray, lat_deg: np.ndarray) -> np.ndarray:
        """Ellipsoidal minus datum height (metres) at WGS 84 longitudes and latitudes (degrees):
        0 for ellipsoidal heights, the geoid undulation N for a geoid-based datum."""
        lon = np.asarray(lon_deg, dtype=float)
        if self.crs is None:
            return np.zeros_like(lon)
        tr = _to_ellipsoidal(self.crs.to_wkt())
        _x, _y, h = tr.transform(lon, np.asarray(lat_deg, dtype=float), np.zeros_like(lon))
        out = np.asarray(h, dtype=float)
        if not np.all(np.isfinite(out)):
            raise VerticalDatumError(f"{self.name}: PROJ returned no height at some positions (outside the geoid grid?)")
        return out

    def to_ellipsoidal(self, lon_deg: np.ndarray, lat_deg: np.ndarray, height_m: np.ndarray) -> np.ndarray:
        """Heights in this datum (metres) to WGS 84 ellipsoidal heights."""
        return np.asarray(height_m, dtype=float) + self.undulation(lon_deg, lat_deg)


def _code(crs: CRS) -> str:
    auth = crs.to_authority()
    return f"{auth[0]}:{auth[1]}" if auth else crs.name


def _vertical_part(crs: CRS) -> CRS | None:
    """The vertical CRS of a compound CRS (None for any other)."""
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_vertical:
                return sub
    return crs if crs.is_vertical else None


def _is_ellipsoidal_3d(crs: CRS) -> bool:
    """A 3D geographic or geocentric CRS: its heights are ellipsoidal."""
    return (crs.is_geographic and len(crs.axis_info) == 3) or crs.is_geocentric


def _from_flag(flag: str) -> VerticalDatum:
    text = flag.strip()
    if text.lower() == ELLIPSOIDAL:
        return VerticalDatum(None, "WGS 84 ellipsoidal heights", "the caller's choice")
    code = NAMES.get(text.lower(), text)
    try:
        crs = CRS.from_user_input(code)
    except (CRSError, ProjError, TypeError):
        raise VerticalDatumError(f"unknown vertical datum {flag!r}: give {CHOICES}") from None
    vertical = _vertical_part(crs)
    if vertical is None:
        if _is_ellipsoidal_3d(crs):
            return VerticalDatum(None, "WGS 84 ellipsoidal heights", "the caller's choice")
        raise VerticalDatumError(f"{flag!r} is not a vertical CRS: give {CHOICES}")
    return VerticalDatum(vertical, vertical.name, "the caller's choice")


def resolve(raster_crs: CRS | None, flag: str | None, where: str = "the DEM") -> VerticalDatum:
    """The vertical datum of a DEM whose raster CRS is ``raster_crs``, given the caller's
    ``flag`` (None: not given). Raises :class:`VerticalDatumError` when neither states one, or
    when they disagree."""
    stated: VerticalDatum | None = None
    if raster_crs is not None:
        vertical = _vertical_part(raster_crs)
        if vertical is not None:
            stated = VerticalDatum(vertical, vertical.name, "the file's CRS")
        elif _is_ellipsoidal_3d(raster_crs):
            stated = VerticalDatum(None, "WGS 84 ellipsoidal heights", "the file's CRS (3D)")
    chosen = _from_flag(flag) if flag is not None else None
    if stated is None and chosen is None:
        horizontal = raster_crs.name if raster_crs is not None else "none"
        raise VerticalDatumError(
            f"{where} does not state its vertical datum (its CRS: {horizontal}): say which heights it holds, "
            f"{CHOICES}. SRTM tiles are EGM96 heights, Copernicus DEM tiles EGM2008 heights"
        )
    if stated is not None and chosen is not None and not _same(stated, chosen):
        raise VerticalDatumError(
            f"{where}'s CRS says its heights are {stated.name}, the flag says {chosen.name}: "
            "correct the file's CRS or drop the flag"
        )
    datum = stated or chosen
    assert datum is not None
    if datum.crs is not None:
        check_offline(datum)
    return datum


def _same(a: VerticalDatum, b: VerticalDatum) -> bool:
    if a.crs is None or b.crs is None:
        return a.crs is None and b.crs is None
    return a.crs.equals(b.crs, ignore_axis_order=True)


@lru_cache(maxsize=1)
def _proj_search_path() -> tuple[str, ...]:
    """PROJ's data directories with the solver's shipped grids appended, and PROJ's network
    access off (once per process)."""
    from pyproj import datadir, network

    network.set_network_enabled(False)  # grids on this machine only, whatever PROJ_NETWORK says
    if DATA_DIR.is_dir():
        present = datadir.get_data_dir().split(";" if ";" in datadir.get_data_dir() else ":")
        if str(DATA_DIR) not in present:
            datadir.append_data_dir(str(DATA_DIR))
    return (datadir.get_data_dir(), datadir.get_user_data_dir())


def _source_crs(vertical_wkt: str) -> CRS:
    """WGS 84 longitude, latitude with heights in the vertical CRS."""
    from pyproj.crs import CompoundCRS

    return CompoundCRS(name="WGS 84 + " + CRS.from_wkt(vertical_wkt).name,
                       components=[CRS.from_epsg(4326), CRS.from_wkt(vertical_wkt)])


@lru_cache(maxsize=8)
def _to_ellipsoidal(vertical_wkt: str) -> Transformer:
    """The best transformation from (lon, lat, datum height) to WGS 84 (lon, lat, ellipsoidal
    height), refused (VerticalDatumError) when it needs a grid that is not on this machine."""
    from pyproj.transformer import TransformerGroup

    _proj_search_path()
    src = _source_crs(vertical_wkt)
    dst = CRS.from_epsg(4979)
    with warnings.catch_warnings():  # pyproj warns of the missing grid: the error below says it
        warnings.simplefilter("ignore", UserWarning)
        group = TransformerGroup(src, dst, always_xy=True, allow_ballpark=False)
    if group.transformers:  # the available ones, best first (no ballpark: that would copy the height)
        return group.transformers[0]
    # PROJ-data's GeoTIFF names first (what projsync and the CDN serve), then the historical ones
    missing = sorted({g.short_name for op in group.unavailable_operations for g in op.grids if not g.available},
                     key=lambda n: (not n.endswith(".tif"), n))
    name = CRS.from_wkt(vertical_wkt).name
    searched = "; ".join(p for p in _proj_search_path() if p)
    if missing:
        others = f" (or {', '.join(missing[1:])})" if len(missing) > 1 else ""
        raise VerticalDatumError(
            f"converting {name} to ellipsoidal heights needs the geoid grid {missing[0]}{others}, which is not on this "
            f"machine, and the network is not used: put the file in one of PROJ's directories ({searched}), e.g. "
            f"`projsync --file {missing[0]}` on a machine with internet access, then copy it; or convert the DEM to "
            "ellipsoidal heights first and say --dem-vertical ellipsoid"
        )
    raise VerticalDatumError(f"PROJ knows no transformation from {name} to WGS 84 ellipsoidal heights")


def check_offline(datum: VerticalDatum) -> None:
    """Raise :class:`VerticalDatumError` when ``datum`` cannot be converted on this machine."""
    if datum.crs is not None:
        _to_ellipsoidal(datum.crs.to_wkt())
