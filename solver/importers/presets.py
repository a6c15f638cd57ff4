"""Sensor presets: the cameras of the source papers as named, versioned camera definitions.

They are the entries of the camera library every server has (the service publishes them in
the shared namespace at start-up, ``service.cameras.ensure_presets``), and what
``pba job --camera NAME`` writes into a job. A version is never changed once published: a
correction is a new version appended to its name's list.

Values and sources (version 1):

- ``prism-backward``, ``prism-nadir``, ``prism-forward``: ALOS PRISM level 1B1 cameras.
  Focal lengths 1999.8762715, 1999.8630195, 2000.0645632 mm (seed 001, Table 1); pixel
  0.0071 mm and line time 0.00037 s (seed 000, section 2 and its 1 pixel = 0.0071 mm);
  16000 lines x 14496 columns (seed 000: the scenes' size; seed 001: 14496 columns from four
  chips); mounting pitch -23.8 / 0 / +23.8 deg (seed 000: omega, phi fixed at 0, -23.8 deg for
  backward; forward symmetric). Chips: the real focal planes (seed 001 section 3, Figure 4):
  chips of 4928 columns (backward, forward) or 4992 (nadir), neighbours overlapping by 32
  columns, four of them making the delivered image (the outer two only in part), at their
  **nominal** places (dx 0, dy the chip centre's offset from the image centre). The papers do
  not print the chips' calibrated offsets: estimate them (a0, b0 per chip, self-calibration)
  or reuse a calibration (``cameras[].iop``). Constants shared with the simulator
  (:mod:`solver.simulate.camera`, where they are cited).
- ``cbers-ccd``: CBERS-2 CCD camera, one chip of 5812 columns, pixel 0.013 mm, focal 520 mm,
  line time 0.00292 s (square 20 m ground pixels at the ~6.65 km/s ground speed from the
  778 km orbit), 5812 lines. Seed 002 uses this sensor but does not print its values; these
  are the simulator's (:func:`solver.simulate.camera.cbers_camera`), consistent with the
  published 20 m GSD and 113 km swath. Check them against your scene's metadata.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

from solver.simulate.camera import (
    PRISM_CHIP_OVERLAP,
    PRISM_COLUMNS,
    PRISM_FOCAL_MM,
    PRISM_FOCAL_PLANE_CHIP_COLUMNS,
    PRISM_LINE_TIME_S,
    PRISM_LINES,
    PRISM_PITCH_DEG,
    PRISM_PIXEL_MM,
    cbers_camera,
    chips_butted,
)


@dataclass(frozen=True)
class Preset:
    """One version of a named camera: its definition (a job camera without ``id``), a
    description and the source of its values."""

    name: str
    version: int
    description: str
    source: str
    definition: dict[str, Any]


def _prism(view: str) -> Preset:
    chips = chips_butted(
        PRISM_FOCAL_PLANE_CHIP_COLUMNS[view], PRISM_CHIP_OVERLAP, PRISM_COLUMNS, PRISM_PIXEL_MM, (0.0,) * 4, (0.0,) * 4
    )
    return Preset(
        f"prism-{view}",
        1,
        f"ALOS PRISM {view} camera, level 1B1 (4 chips, nominal chip offsets)",
        "focal length: seed 001 Table 1; pixel, line time, size, mounting: seed 000; chips: seed 001 section 3",
        {
            "focal_mm": PRISM_FOCAL_MM[view],
            "pixel_mm": PRISM_PIXEL_MM,
            "line_time_s": PRISM_LINE_TIME_S,
            "lines": PRISM_LINES,
            "columns": PRISM_COLUMNS,
            "mounting_pitch_deg": PRISM_PITCH_DEG[view],
            "chips": [
                {"id": c.id, "first_column": c.first_column, "columns": c.columns, "dx_mm": c.dx_mm, "dy_mm": round(c.dy_mm, 9)}
                for c in chips
            ],
        },
    )


def _cbers() -> Preset:
    cam = cbers_camera().to_job()
    cam.pop("id")
    cam["chips"] = []  # one chip centred on the principal point: the schema's default
    return Preset(
        "cbers-ccd",
        1,
        "CBERS-2 CCD camera (one chip, 20 m GSD)",
        "not printed in seed 002; 20 m GSD, 113 km swath from 778 km (the simulator's values)",
        cam,
    )


PRESETS: dict[str, list[Preset]] = {
    p.name: [p] for p in (_prism("backward"), _prism("nadir"), _prism("forward"), _cbers())
}


def preset_names() -> list[str]:
    return sorted(PRESETS)


def get_preset(name: str, version: int | None = None) -> Preset | None:
    """A preset version (the latest when ``version`` is None); None when unknown."""
    versions = PRESETS.get(name)
    if not versions:
        return None
    if version is None:
        return versions[-1]
    return next((p for p in versions if p.version == version), None)


def preset_camera(name: str, camera_id: str | None = None, version: int | None = None) -> dict[str, Any] | None:
    """A complete job camera (``id`` default: the name) from a preset; None when unknown."""
    p = get_preset(name, version)
    if p is None:
        return None
    return {"id": camera_id or name, **copy.deepcopy(p.definition)}
