"""A DEM degraded like a real one, from a terrain with known heights: the truth sampled at the
centres of geographic cells (1 arc second, about 30 m: the Copernicus DEM's and SRTM1's
spacing), plus a known bias and a noise correlated over a few cells, written as a GeoTIFF.

Real DEM errors are correlated over hundreds of metres (SRTM's over about 1 km), not
independent per cell: a Gaussian-filtered white noise, scaled so that its standard deviation
at a cell is ``noise_m``, has that property; heights interpolated between cells keep nearly
the same standard deviation (not the half of independent cells). What the adjustment must not
know is the bias: its heights then sit ``bias_m`` above the truth, and the DEM bias test must
find it where other data (control, priors) fix the height.

Heights are WGS 84 ellipsoidal, stated in the file's CRS (EPSG:4979) unless ``vertical`` is
``egm96``: then the file holds EGM96 heights (the truth minus the undulation, converted by
PROJ here, independently of the solver's reader) under the compound CRS EPSG:4326+5773, as a
user would get from SRTM.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

ARCSEC = 1.0 / 3600.0
GRIDS = Path(__file__).resolve().parents[1] / "geometry" / "data"  # the shipped EGM96 grid (a file, not the solver's code)
VERTICAL_CRS = {"egm96": "EPSG:5773"}


@dataclass(frozen=True)
class DemDegradation:
    """How the simulated DEM differs from the truth: its cell (arc seconds), the noise's
    standard deviation (m) and correlation length (cells, the Gaussian filter's sigma), the
    bias (m, added to every cell), the seed of the noise and the vertical datum of the file."""

    cell_arcsec: float = 1.0
    noise_m: float = 3.0
    correlation_cells: float = 1.5
    bias_m: float = 0.0
    seed: int = 0
    vertical: str = "ellipsoid"


def correlated_noise(shape: tuple[int, int], sigma_m: float, correlation_cells: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian-filtered white noise of standard deviation ``sigma_m`` at every cell (the filter
    normalised analytically: a unit white noise filtered by a 2D Gaussian of sigma s cells has
    variance 1 / (4 pi s^2), for s above about 1)."""
    from scipy.ndimage import gaussian_filter

    white = rng.standard_normal(shape)
    if correlation_cells <= 0:
        return sigma_m * white
    smooth = gaussian_filter(white, correlation_cells, mode="wrap")
    return sigma_m * smooth * np.sqrt(4.0 * np.pi * correlation_cells**2)


def _ellipsoidal_to(crs: str, lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Ellipsoidal heights to heights in the compound ``crs``, by PROJ directly (the
    simulator's own call, in the direction opposite to the solver's reader)."""
    from pyproj import CRS, Transformer, datadir

    if str(GRIDS) not in datadir.get_data_dir():
        datadir.append_data_dir(str(GRIDS))
    tr = Transformer.from_crs(CRS.from_epsg(4979), CRS.from_user_input(crs), always_xy=True, only_best=True)
    out = np.asarray(tr.transform(lon.ravel(), lat.ravel(), h.ravel())[2]).reshape(h.shape)
    if not np.all(np.isfinite(out)):
        raise ValueError(f"PROJ could not convert to {crs} (is its geoid grid on this machine?)")
    return out


def degraded_dem(height: Callable[[np.ndarray, np.ndarray], np.ndarray], bounds_lon_lat: tuple[float, float, float, float],
                 degradation: DemDegradation, path: Path | str) -> dict:
    """Write the degraded DEM of the terrain ``height(lon, lat)`` (ellipsoidal metres) over
    ``bounds_lon_lat`` (west, south, east, north, degrees) to ``path``; returns what was done
    (cells, the noise's realised standard deviation and mean, the bias)."""
    from affine import Affine

    from solver.raster_gate import create_raster

    d = degradation.cell_arcsec * ARCSEC
    w, s, e, n = bounds_lon_lat
    cols, rows = int(np.ceil((e - w) / d)), int(np.ceil((n - s) / d))
    lon = w + (np.arange(cols) + 0.5) * d
    lat = n - (np.arange(rows) + 0.5) * d
    glon, glat = np.meshgrid(lon, lat)
    truth = np.asarray(height(glon, glat), dtype=float)
    rng = np.random.default_rng(degradation.seed)
    noise = correlated_noise(truth.shape, degradation.noise_m, degradation.correlation_cells, rng)
    values = truth + noise + degradation.bias_m
    crs = "EPSG:4979"
    if degradation.vertical != "ellipsoid":
        code = VERTICAL_CRS[degradation.vertical]
        crs = "EPSG:4326+" + code.split(":")[1]
        values = _ellipsoidal_to(crs, glon, glat, values)
    profile = dict(driver="GTiff", dtype="float32", width=cols, height=rows, count=1, crs=crs,
                   transform=Affine(d, 0.0, w, 0.0, -d, n), compress="deflate", nodata=-32768.0)
    with create_raster(path, **profile) as dst:
        dst.write(values.astype(np.float32), 1)
    return {"cells": [rows, cols], "cell_arcsec": degradation.cell_arcsec, "bias_m": degradation.bias_m,
            "noise_std_m": float(noise.std()), "noise_mean_m": float(noise.mean()), "crs": crs}


def write_dem_of_truth(truth: dict, path: Path, noise_m: float, seed: int, margin_deg: float = 0.02) -> Path:
    """A DEM for a simulated scene: its true terrain (``truth["terrain"]``, as ``pba simulate``
    writes it) degraded by ``noise_m`` of correlated noise (seed ``seed``) over the truth's
    points plus ``margin_deg``, written to ``path`` (GeoTIFF, ellipsoidal heights). The job reads
    it as a user's would (``pba job --dem``), through the solver's own reader: the simulator
    only writes files, so a reader error cannot cancel against it."""
    from solver.simulate.terrain import Terrain

    terrain = Terrain(**{k: tuple(v) if isinstance(v, list) else v for k, v in truth["terrain"].items()})
    lon = [p["lon_deg"] for p in truth["points"]]
    lat = [p["lat_deg"] for p in truth["points"]]
    bounds = (min(lon) - margin_deg, min(lat) - margin_deg, max(lon) + margin_deg, max(lat) + margin_deg)
    degraded_dem(terrain.height, bounds, DemDegradation(noise_m=noise_m, seed=seed), path)
    return path
