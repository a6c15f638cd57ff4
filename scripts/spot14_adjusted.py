"""The 'Adjusted' column of docs/sensor-metadata.md's SPOT 1-4 table, on real METADATA.DIM files.

    .venv/bin/python scripts/spot14_adjusted.py METADATA.DIM [...]

For each file: the job ``pba job --sensor`` composes from it, with 17 control and 26 check
points imaged by the file's exact model (the attitude included) at 0-2000 m, every observation
of the job perturbed as its weights say (tests/solver/sensors/spot14_jobs.py, as the tests do on
the simulated scene); three seeds; sigma0, the global test and the check points' horizontal
RMSE in ground sampling distances. The public SPOT 1-4 files we know (COSI-Corr's test data)
forbid commercial use: they are measured, never committed.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


class RealScene:
    """The scene interface of spot14_jobs.truth_job over a real product: its size from the
    file's corners, the ground of an image position by the file's exact model (ECEF m)."""

    def __init__(self, product) -> None:  # noqa: ANN001 (a solver.sensors.dimap_spot5.Spot5Product)
        self.product = product
        self.lines = int(product.corners[:, 0].max()) + 1
        self.columns = int(product.corners[:, 1].max()) + 1

    def ground(self, line: np.ndarray, column: np.ndarray, h: np.ndarray) -> np.ndarray:
        return self.product.model.image_to_ecef(line, column, h)

    def geodetic(self, ecef: np.ndarray) -> np.ndarray:
        from solver.geometry.geodesy import ecef_to_geodetic

        return ecef_to_geodetic(ecef)


def main(paths: list[str]) -> None:
    sys.path[:0] = [str(ROOT)]
    # after the package (tests/solver is a folder of tests, not it): the test scenes' helpers
    sys.path += [str(ROOT / "tests" / "utils"), str(ROOT / "tests"), str(ROOT / "tests" / "solver" / "sensors")]
    from spot14_jobs import truth_job

    from solver.api import run
    from solver.sensors.dimap_spot5 import read_spot5

    for path in paths:
        product = read_spot5(Path(path))
        scene = RealScene(product)
        out = []
        for seed in (1, 2, 3):
            rep = run(truth_job(scene, product, 17, 26, seed, perturb=True))
            a, cp = rep["adjustment"], rep["checkpoints"]
            gsd = rep["images"][0]["gsd_m"]
            rmse = np.hypot(cp["rmse_m"]["e"], cp["rmse_m"]["n"]) / gsd
            out.append(f"sigma0 {a['sigma0_aposteriori']:.2f} {'passed' if a['chi2']['passed'] else 'FAILED'} check {rmse:.2f} GSD")
        print(Path(path).name, product.mission, " | ".join(out), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
