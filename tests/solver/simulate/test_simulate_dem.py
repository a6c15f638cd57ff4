"""The degraded-DEM simulator (solver.simulate.dem) read back by the adjustment's DEM reader
(solver.geometry.dem): at random positions, the DEM's height minus the terrain's true height
has the known bias as its mean and the stated noise as its standard deviation; an EGM96 file
holds the truth minus the geoid and reads back as the truth."""

from __future__ import annotations

import numpy as np
import pytest

from solver.geometry.dem import read_dem
from solver.simulate.dem import DemDegradation, degraded_dem
from solver.simulate.terrain import Terrain

BOUNDS = (5.10, 44.10, 5.20, 44.18)  # about 8 x 9 km: 360 x 288 one-arc-second cells
TERRAIN = Terrain(5.15, 44.14, min_height_m=300.0, max_height_m=900.0)
SAMPLES = 4000
# interpolating the smooth terrain between 30 m cells: well under a decimetre (wavelengths >= 2.9 km)
INTERPOLATION_M = 0.1


def _errors(path, vertical=None, seed=5):
    dem = read_dem(path, vertical)
    rng = np.random.default_rng(seed)
    lon = rng.uniform(BOUNDS[0] + 0.005, BOUNDS[2] - 0.005, SAMPLES)
    lat = rng.uniform(BOUNDS[1] + 0.005, BOUNDS[3] - 0.005, SAMPLES)
    return dem.sample(lon, lat)[0] - TERRAIN.height(lon, lat)


def test_noise_and_bias_are_as_stated(tmp_path) -> None:
    path = tmp_path / "dem.tif"
    done = degraded_dem(TERRAIN.height, BOUNDS, DemDegradation(noise_m=3.0, bias_m=-4.0, seed=2), path)
    assert done["crs"] == "EPSG:4979"
    assert done["noise_std_m"] == pytest.approx(3.0, rel=0.1)  # the analytic normalisation of the filter
    err = _errors(path)
    # correlated over ~1.5 cells: the 4000 samples are worth some hundreds of independent ones
    assert np.mean(err) == pytest.approx(-4.0 + done["noise_mean_m"], abs=INTERPOLATION_M + 0.1)
    assert np.mean(err) == pytest.approx(-4.0, abs=0.5)
    # interpolated between correlated cells the noise keeps most of its standard deviation
    assert 0.8 * 3.0 < np.std(err) < 1.05 * 3.0


def test_no_noise_reads_back_the_truth_in_either_vertical_datum(tmp_path) -> None:
    for vertical in ("ellipsoid", "egm96"):
        path = tmp_path / f"{vertical}.tif"
        done = degraded_dem(TERRAIN.height, BOUNDS, DemDegradation(noise_m=0.0, vertical=vertical), path)
        err = _errors(path)
        assert np.max(np.abs(err)) < INTERPOLATION_M, vertical
    assert done["crs"] == "EPSG:4326+5773"
    raw = read_dem(path, None)
    assert raw.vertical.to_dict()["crs"] == "EPSG:5773"  # stated by the file, not assumed
    # the file's own values: the truth minus the geoid undulation (about 50 m here)
    a, _, c, _, e, f = raw.transform
    lon, lat = np.array([c + 100.5 * a]), np.array([f + 80.5 * e])
    undulation = raw.vertical.undulation(lon, lat)[0]
    assert 45.0 < undulation < 55.0
    assert raw.values[80, 100] == pytest.approx(TERRAIN.height(lon, lat)[0] - undulation, abs=1e-3)  # float32 of ~600 m
