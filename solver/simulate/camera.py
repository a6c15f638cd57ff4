"""Linear-array cameras: focal plane, CCD chips and line timing.

Conventions shared with the solver (:mod:`solver.schema.job`): camera axes x_c along track (flight
direction), z_c away from the scene, y_c = z_c x x_c. A point with camera coordinates
(X, Y, Z), Z < 0, images at focal-plane coordinates x = -f X / Z, y = -f Y / Z (mm). A chip
covers image columns ``first_column .. first_column + columns - 1``; its pixels lie at
x = dx_mm (along-track stagger) and y = dy_mm + (C - first_column - (columns - 1)/2) * pixel_mm,
so the column of a focal-plane y is ``C = first_column + (columns - 1)/2 + (y - dy_mm) / pixel_mm``.
Chips may overlap and extend beyond the delivered image; a column covered by several chips
belongs to the one the solver assigns it to (:mod:`solver.geometry.sensor`: the nearest chip centre).
Lines grow with time: t(L) = first_line_time + L * line_time (L continuous). The origin of
(line, column) is the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.geometry.sensor import chip_index_of_column, chip_seams
from solver.simulate.iop import NO_IOP, CameraIOP

# Seed 001 Table 1: calibrated focal lengths of the PRISM cameras (mm)
PRISM_FOCAL_MM = {"backward": 1999.8762715, "nadir": 1999.8630195, "forward": 2000.0645632}
PRISM_PITCH_DEG = {"backward": -23.8, "nadir": 0.0, "forward": 23.8}
PRISM_PIXEL_MM = 0.0071
PRISM_LINE_TIME_S = 0.00037
PRISM_LINES = 16000
PRISM_COLUMNS = 14496
# Four chips assembled into the 14496-column image (seed 001 section 3, Figure 4), as an
# invented partition of the image ("partition" layout, the default of the presets).
PRISM_CHIP_COLUMNS = (3616, 3632, 3632, 3616)
# The real focal planes (seed 001 section 3): six chips of 4992 columns (nadir) or eight of 4928
# (backward, forward), neighbours overlapping by 32 columns; four of them make the delivered
# image, the outer two only in part ("butted" layout: the four chips with their full width,
# the outer ones starting before column 0 and ending after column 14495).
PRISM_FOCAL_PLANE_CHIP_COLUMNS = {"backward": 4928, "nadir": 4992, "forward": 4928}
PRISM_CHIP_OVERLAP = 32
PRISM_LAYOUTS = ("partition", "butted")
# Small departures of each chip from its nominal place (mm): along-track stagger dx and an
# across-track shift added to the nominal dy. Fixed "calibration" values, per camera.
_PRISM_CHIP_DX_MM = {
    "backward": (0.0142, -0.0035, 0.0213, -0.0071),
    "nadir": (-0.0107, 0.0036, 0.0178, -0.0142),
    "forward": (0.0071, -0.0178, 0.0036, 0.0249),
}
_PRISM_CHIP_DY_SHIFT_MM = {
    "backward": (0.0012, -0.0007, 0.0004, -0.0010),
    "nadir": (-0.0009, 0.0011, -0.0005, 0.0008),
    "forward": (0.0006, -0.0012, 0.0010, -0.0004),
}


@dataclass(frozen=True)
class ChipSpec:
    """One CCD chip: its image columns and its offsets from the principal point (mm)."""

    id: str
    first_column: int
    columns: int
    dx_mm: float = 0.0
    dy_mm: float = 0.0

    @property
    def centre_column(self) -> float:
        return self.first_column + (self.columns - 1) / 2.0


@dataclass(frozen=True)
class CameraSpec:
    """A pushbroom camera (see module docstring for the conventions)."""

    id: str
    focal_mm: float
    pixel_mm: float
    line_time_s: float
    lines: int
    columns: int
    chips: tuple[ChipSpec, ...]
    mounting_pitch_deg: float = 0.0
    iop: CameraIOP = NO_IOP  # true interior-orientation errors (not written in the job)

    def __post_init__(self) -> None:
        if np.any(self.chip_of_column(np.arange(self.columns)) < 0):
            raise ValueError(f"camera {self.id}: the chips must cover every image column 0..{self.columns - 1}")

    def column_from_y(self, y_mm: np.ndarray, chip: int) -> np.ndarray:
        """Image column of focal-plane y (mm) on chip index ``chip``."""
        c = self.chips[chip]
        return c.centre_column + (np.asarray(y_mm) - c.dy_mm) / self.pixel_mm

    def chip_of_column(self, column: np.ndarray) -> np.ndarray:
        """Chip index of image columns by the solver's rule (:mod:`solver.geometry.sensor`); -1 on no chip."""
        return chip_index_of_column([c.first_column for c in self.chips], [c.columns for c in self.chips], column)

    def seams(self) -> np.ndarray:
        """Columns inside the image where one chip hands over to the next (half-integers)."""
        return chip_seams([c.first_column for c in self.chips], [c.columns for c in self.chips], self.columns)

    def focal_from_image(self, column: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_mm, y_mm, chip index) of image columns (the line only gives the time)."""
        col = np.asarray(column, dtype=float)
        k = self.chip_of_column(col)
        if np.any(k < 0):
            raise ValueError("column outside the image")
        dx = np.array([c.dx_mm for c in self.chips])[k]
        dy = np.array([c.dy_mm for c in self.chips])[k]
        cc = np.array([c.centre_column for c in self.chips])[k]
        return dx, dy + (col - cc) * self.pixel_mm, k

    @property
    def true_focal_mm(self) -> float:
        """Focal length of the simulated camera: nominal + the IOP error ``df``."""
        return self.focal_mm + self.iop.value("df")

    def image_plane(self, column: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_i, y_i, chip index) of image columns in the simulated camera: the focal-plane
        point (mm, from the principal point) whose direction ``(x_i, y_i, -true_focal_mm)`` the
        pixel sees, with the IOP errors applied (:mod:`solver.simulate.iop`)."""
        x, y, k = self.focal_from_image(column)
        if self.iop.is_zero:
            return x, y, k
        dy = np.array([c.dy_mm for c in self.chips])[k]
        ids = np.array([c.id for c in self.chips])[k]
        length = np.array([c.columns * self.pixel_mm for c in self.chips])[k]
        xi, yi = self.iop.image_point(y - dy, x, dy, ids, length)
        return xi, yi, k

    def gsd_nadir_m(self, height_m: float) -> float:
        return self.pixel_mm / self.focal_mm * height_m

    def to_job(self) -> dict:
        """The camera as a :class:`solver.schema.job.Camera` document."""
        return {
            "id": self.id,
            "focal_mm": self.focal_mm,
            "pixel_mm": self.pixel_mm,
            "line_time_s": self.line_time_s,
            "lines": self.lines,
            "columns": self.columns,
            "mounting_pitch_deg": self.mounting_pitch_deg,
            "chips": [
                {"id": c.id, "first_column": c.first_column, "columns": c.columns, "dx_mm": c.dx_mm, "dy_mm": c.dy_mm}
                for c in self.chips
            ],
        }


def chips_partition(
    widths: tuple[int, ...], pixel_mm: float, dx_mm: tuple[float, ...], dy_shift_mm: tuple[float, ...]
) -> tuple[ChipSpec, ...]:
    """Chips side by side over ``sum(widths)`` columns; dy is the chip centre's nominal offset
    from the image centre plus ``dy_shift_mm``."""
    total = sum(widths)
    chips, first = [], 0
    for i, (w, dx, sh) in enumerate(zip(widths, dx_mm, dy_shift_mm, strict=True)):
        chips.append(_nominal_chip(i, first, w, total, pixel_mm, dx, sh))
        first += w
    return tuple(chips)


def _nominal_chip(i: int, first: int, width: int, image_columns: int, pixel_mm: float, dx_mm: float, dy_shift_mm: float) -> ChipSpec:
    """Chip ``str(i + 1)`` at its nominal place: dy (mm) the offset of its centre column from the
    image centre, plus ``dy_shift_mm``; x = ``dx_mm``."""
    nominal = (first + (width - 1) / 2.0 - (image_columns - 1) / 2.0) * pixel_mm
    return ChipSpec(str(i + 1), first, width, float(dx_mm), float(nominal + dy_shift_mm))


def chips_butted(
    width: int, overlap: int, image_columns: int, pixel_mm: float, dx_mm: tuple[float, ...], dy_shift_mm: tuple[float, ...]
) -> tuple[ChipSpec, ...]:
    """``len(dx_mm)`` chips of ``width`` columns, neighbours overlapping by ``overlap`` columns,
    centred on an image of ``image_columns`` (the outer chips start before column 0 and end after
    the last column); dy is the chip centre's nominal offset from the image centre plus
    ``dy_shift_mm``, so every chip sees a column where the others see it."""
    n = len(dx_mm)
    span = n * width - (n - 1) * overlap
    first0 = -((span - image_columns) // 2)
    chips = []
    for i, (dx, sh) in enumerate(zip(dx_mm, dy_shift_mm, strict=True)):
        chips.append(_nominal_chip(i, first0 + i * (width - overlap), width, image_columns, pixel_mm, dx, sh))
    return tuple(chips)


def prism_chips(view: str, layout: str = "partition") -> tuple[ChipSpec, ...]:
    """The four chips of a PRISM-like view: ``partition`` (side by side over the image) or
    ``butted`` (the real focal-plane chips, overlapping by 32 columns, seed 001 section 3)."""
    if layout == "partition":
        return chips_partition(PRISM_CHIP_COLUMNS, PRISM_PIXEL_MM, _PRISM_CHIP_DX_MM[view], _PRISM_CHIP_DY_SHIFT_MM[view])
    if layout == "butted":
        return chips_butted(
            PRISM_FOCAL_PLANE_CHIP_COLUMNS[view], PRISM_CHIP_OVERLAP, PRISM_COLUMNS, PRISM_PIXEL_MM,
            _PRISM_CHIP_DX_MM[view], _PRISM_CHIP_DY_SHIFT_MM[view],
        )
    raise ValueError(f"unknown PRISM chip layout {layout!r} (one of {', '.join(PRISM_LAYOUTS)})")


def prism_camera(view: str, layout: str = "partition") -> CameraSpec:
    """A PRISM-like camera: ``backward``, ``nadir`` or ``forward`` (seed 001 Table 1), with the
    chip ``layout`` of :func:`prism_chips`."""
    if view not in PRISM_FOCAL_MM:
        raise ValueError(f"unknown PRISM view {view!r}")
    return CameraSpec(
        id=f"prism-{view}",
        focal_mm=PRISM_FOCAL_MM[view],
        pixel_mm=PRISM_PIXEL_MM,
        line_time_s=PRISM_LINE_TIME_S,
        lines=PRISM_LINES,
        columns=PRISM_COLUMNS,
        chips=prism_chips(view, layout),
        mounting_pitch_deg=PRISM_PITCH_DEG[view],
    )


def cbers_camera() -> CameraSpec:
    """A CBERS-like CCD camera: ~20 m GSD from ~778 km, 5812 columns of 13 um, f = 520 mm.

    The line time (2.92 ms) gives square ground pixels at the ~6.65 km/s ground speed.
    """
    return CameraSpec(
        id="cbers-ccd",
        focal_mm=520.0,
        pixel_mm=0.013,
        line_time_s=0.00292,
        lines=5812,
        columns=5812,
        chips=(ChipSpec("1", 0, 5812, 0.0, 0.0),),
        mounting_pitch_deg=0.0,
    )


def simple_camera(
    id: str,
    focal_mm: float,
    pixel_mm: float,
    line_time_s: float,
    lines: int,
    columns: int,
    mounting_pitch_deg: float = 0.0,
) -> CameraSpec:
    """Any other single-chip sensor, by its parameters."""
    return CameraSpec(id, focal_mm, pixel_mm, line_time_s, lines, columns, (ChipSpec("1", 0, columns),), mounting_pitch_deg)
