"""The vectorised chip lookup of validation and assembly against the per-observation rule.

:func:`solver.geometry.sensor.chip_indices` must give, for every column and chip name,
what :func:`solver.geometry.sensor.camera_chip` gives one observation at a time (its chip, or
-1 where it raises KeyError); tests/solver/observations/test_chips.py pins that rule itself (the seam, the tie to
the later centre, named chips) against the simulator.
"""

from __future__ import annotations

import numpy as np

from solver.geometry.sensor import camera_chip, chip_indices, chip_of_index
from solver.schema.job import Camera

# two chips of 100 columns overlapping by 32 (as in tests/solver/observations/test_chips.py), image columns 0..147
TWO = {
    "id": "two",
    "focal_mm": 1000.0,
    "pixel_mm": 0.01,
    "line_time_s": 1e-3,
    "lines": 100,
    "columns": 148,
    "chips": [
        {"id": "a", "first_column": -10, "columns": 100, "dx_mm": 0.001, "dy_mm": -0.34},
        {"id": "b", "first_column": 58, "columns": 100, "dx_mm": -0.002, "dy_mm": 0.34},
    ],
}
NO_CHIPS = {k: v for k, v in TWO.items() if k != "chips"}


def _one_at_a_time(cam: Camera, cols, names) -> list:
    out = []
    for c, n in zip(cols, names):
        try:
            out.append(camera_chip(cam, float(c), n))
        except KeyError:
            out.append(None)
    return out


def test_chip_indices_equal_camera_chip_for_every_column_and_name():
    # every half column over the image and half a pixel beyond, the seam (73.5), the chip ends
    cols = np.concatenate([np.arange(-2.0, 150.0, 0.5), [73.4, 73.5, 73.6, 147.5, -0.5, 147.50001]])
    for spec in (TWO, NO_CHIPS):
        cam = Camera(**spec)
        for name in (None, "a", "b", "1", "zz"):
            names = [name] * len(cols)
            want = _one_at_a_time(cam, cols, names)
            got = chip_indices(cam, cols, names)
            assert [None if k < 0 else chip_of_index(cam, int(k)) for k in got] == want, (spec["id"], name)
    # mixed names in one call
    cam = Camera(**TWO)
    rng = np.random.default_rng(3)
    cols = rng.uniform(-3.0, 151.0, 500)
    names = list(rng.choice(np.array([None, "a", "b", "x"], dtype=object), 500))
    got = chip_indices(cam, cols, names)
    assert [None if k < 0 else chip_of_index(cam, int(k)) for k in got] == _one_at_a_time(cam, cols, names)
