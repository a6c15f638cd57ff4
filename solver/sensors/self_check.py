"""The self-check of a vendor product: everything the file states that we did not fit, against
the exact model *and* against the job form (the orientation the job will solve from), with
thresholds (the role of ASP's ``cam_test``; ``pba check-sensor``, and ``pba import-sensor``,
which warns above them).

References, each where the format has it:

- the vendor's located points: SPOT 1-5 tie points (corners) and ``Scene_Center`` (SPOT 1-4
  locate them without the attitude: the exact model without it is compared with them, the job
  form with them moved by the attitude's effect at the same image position); DIMAP v2 and
  Pleiades ground-segment extent corners (and a ``Center`` that is not their mean; without
  heights, each at the height that fits it best: only its miss across the height direction
  counts, as the vendor placed them on its terrain); Maxar's first-line first-column corner
  (``IMD/BAND_x`` ``ULLON``, ``ULLAT``, ``ULHAE``; the other three corners bound the band's
  valid pixels, which the file does not place: on five of seven public WorldView products they
  lie 84-772 lines and 508-660 columns inside the last line and column, where the exact model
  and the RPC put them alike); CBERS corners, each predicted from the other three (the model is
  fitted to them). Distance in pixels: the point projected by the model against the image
  position the vendor gives it; in metres: the model's ground point at that position and height
  against the vendor's;
- the vendor's RPC (Maxar's RPB, the Pleiades RFM, a DIMAP v2 ``RPC_*.XML`` beside the file) or
  one given (``--rpc``): over 11 x 11 image positions x 5 heights of its range, each image
  position taken to the ground by the model and back by the RPC;
- the job form over the whole image: the job composed from the file (the fragment of
  :mod:`solver.sensors.job_fragment`), its orientation as delivered, i.e. the platform model,
  its orbit fitted to the ephemeris as the job weights it and its attitude (the delivered
  samples as its base and the polynomials' correction fitted to them) (:class:`solver.gis.model.AdjustedModel` without a report: what ``pba ground-to-image
  job.json -`` uses and what the adjustment starts from), against the exact model over 9 x 9
  image positions x 3 heights. The job needs observations to be valid: five control points are
  added, weighted 10 km so that they do not move it (moved by 1 km, they change nothing).

Thresholds (maximum distance): :data:`LIMITS_PX` per reference; in metres the same at the
image's ground sample distance.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.geometry.geodesy import geodetic_to_ecef
from solver.geometry.rpc import RPC
from solver.sensors.linescan import LinescanModel

LIMITS_PX = {"point": 2.0, "rpc": 1.0, "job": 0.5}  # vendor corners and centres; an RPC; the job form vs the exact model
JOB_GRID = 9  # job form: JOB_GRID x JOB_GRID image positions ...
JOB_HEIGHTS_M = (-500.0, 0.0, 500.0)  # ... at the product's mean height plus these
RPC_GRID, RPC_HEIGHTS = 11, 5
CONTROL_SIGMA_M = 1e4  # the job form's placeholder control points: weighted so as not to move it


@dataclass
class VendorPoints:
    """Located points the file states: (n, 5) line, column (0-based), lon, lat, h, and a name."""

    name: str
    rows: np.ndarray
    fitted_height: bool = False  # h is the height fitted to each (the file gives none)
    # the model the vendor located them with, when it is not the exact model (SPOT 1-4: without
    # the attitude); the job form is then compared with them moved by the difference
    located_by: LinescanModel | None = None


@dataclass
class CheckRow:
    """One reference against one model: distances in pixels and metres, and the limit."""

    reference: str
    model: str  # "exact" or "job form"
    points: int
    rms_px: float
    max_px: float
    rms_m: float | None
    max_m: float | None
    limit_px: float
    limit_m: float | None

    @property
    def passed(self) -> bool:
        return bool(np.isfinite(self.max_px) and self.max_px <= self.limit_px)

    def as_dict(self) -> dict[str, Any]:
        return {"reference": self.reference, "model": self.model, "points": self.points, "rms_px": self.rms_px,
                "max_px": self.max_px, "rms_m": self.rms_m, "max_m": self.max_m, "limit_px": self.limit_px,
                "limit_m": self.limit_m, "passed": self.passed}


@dataclass
class SelfCheck:
    """The rows of one product's self-check and what could not be checked (``notes``)."""

    file: str
    satellite: str
    rows: list[CheckRow] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.rows)

    def failures(self) -> list[CheckRow]:
        return [r for r in self.rows if not r.passed]


def _stats(d: np.ndarray) -> tuple[float, float]:
    ok = np.isfinite(d)
    if not ok.all():  # a point the model cannot project: as far as it can be
        return float("inf"), float("inf")
    return float(np.sqrt(np.mean(d**2))), float(d.max())


def pixel_size_m(model: LinescanModel, line: np.ndarray, column: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Ground size (m) of one pixel at image positions: the mean of its line and column steps."""
    g = model.image_to_ecef(line, column, h)
    gl = model.image_to_ecef(line + 1.0, column, h)
    gc = model.image_to_ecef(line, column + 1.0, h)
    return 0.5 * (np.linalg.norm(gl - g, axis=1) + np.linalg.norm(gc - g, axis=1))


HEIGHT_SEARCH_M = (-500.0, 9000.0)  # where a point given without a height is looked for


def best_heights(model: LinescanModel, rows: np.ndarray) -> np.ndarray:
    """For each (line, column, lon, lat) row, the height (m) at which the model's ground point
    of the image position comes closest to the point's longitude and latitude (a grid refined
    four times: to about 0.1 m)."""
    lo, hi = np.full(rows.shape[0], HEIGHT_SEARCH_M[0]), np.full(rows.shape[0], HEIGHT_SEARCH_M[1])
    for _ in range(4):
        hs = np.linspace(lo, hi, 41)  # (41, n)
        d = np.array([np.linalg.norm(model.image_to_ecef(rows[:, 0], rows[:, 1], h)
                                     - geodetic_to_ecef(np.column_stack([rows[:, 2], rows[:, 3], h])), axis=1) for h in hs])
        k = np.argmin(d, axis=0)
        step = hs[1] - hs[0]
        best = hs[k, np.arange(rows.shape[0])]
        lo, hi = best - step, best + step
    return best


def vendor_points(product: Any) -> tuple[list[VendorPoints], list[str]]:
    """The located points a product states (module docstring) and notes on those left out: its
    registered reader's ``points`` (:mod:`solver.sensors.readers`)."""
    from solver.sensors.readers import reader_of

    return reader_of(product).points_of(product)


def spot5_points(product: Any) -> tuple[list[VendorPoints], list[str]]:
    """DIMAP v1 (SPOT 1-5): the tie points inside the look-angle table and the scene centre."""
    notes: list[str] = []
    m = product.model
    c = product.corners
    inside = (c[:, 1] >= 0) & (c[:, 1] <= m.columns - 1)
    if (~inside).any():
        notes.append(f"{int((~inside).sum())} tie points lie beyond the look-angle table's columns: not checked")
    sysm = product.systematic
    if sysm is not None:
        notes.append("SPOT 1-4 locate their tie points and scene centre without the attitude: the exact model is "
                     "compared with them without it, the job form with them moved by the attitude's effect")
    tag = ", located without the attitude" if sysm is not None else ""
    out = [VendorPoints(f"corners (tie points{tag})", c[inside], located_by=sysm)] if inside.any() else []
    if product.centre.shape[0]:
        out.append(VendorPoints(f"scene centre{' (' + tag[2:] + ')' if tag else ''}", product.centre, located_by=sysm))
    elif c.shape[0]:
        notes.append("the Dataset_Frame's scene centre is not checked: its vertices are not the tie points")
    return out, notes


def dimap_v2_points(product: Any) -> tuple[list[VendorPoints], list[str]]:
    """DIMAP v2 (SPOT 6/7, Pleiades): the extent corners, each at its best height when they state none."""
    m = product.model
    c = product.corners
    if c.shape[0] == 0:
        return [], ["the product states no extent corners"]
    if np.all(np.isfinite(c[:, 4])):
        return [VendorPoints("extent corners", c)], []
    rows = c.copy()
    rows[:, 4] = best_heights(m, c)
    notes = ["the extent corners state no height: each is compared at the height that brings it closest "
             f"({rows[:, 4].min():.0f} to {rows[:, 4].max():.0f} m), so only its miss across that direction counts"]
    return [VendorPoints("extent corners (each at its best height)", rows, True)], notes


def maxar_points(product: Any) -> tuple[list[VendorPoints], list[str]]:
    """Maxar: the first-line first-column corner (the others bound the valid pixels only)."""
    notes: list[str] = []
    c = product.corners
    ul = c[(c[:, 0] == 0) & (c[:, 1] == 0)] if c.shape[0] else c
    if c.shape[0] > ul.shape[0]:
        notes.append("Maxar's UR, LR and LL corners bound the band's valid pixels, whose extent the file does not "
                     "give: not checked")
    return ([VendorPoints("first-line first-column corner (IMD ULLON, ULLAT, ULHAE)", ul)] if ul.shape[0] else []), notes


def cbers_points(product: Any) -> tuple[list[VendorPoints], list[str]]:
    """INPE CBERS: the corners the model is fitted to (each checked from the other three)."""
    notes = ["the model is fitted to the record's corners: the corners are checked each from the other three; "
             "the centre CT is not the image's centre (it lies 12-16 km along track from the corners' centre)"]
    return [VendorPoints("corners", product.corners[product.corners_used])], notes


def _exact_point_row(model: LinescanModel, vp: VendorPoints, limit_px: float) -> CheckRow:
    model = vp.located_by or model
    r = vp.rows
    back = model.ground_to_image(r[:, 2:5])
    px = np.hypot(back[:, 0] - r[:, 0], back[:, 1] - r[:, 1])
    m = np.linalg.norm(model.image_to_ecef(r[:, 0], r[:, 1], r[:, 4]) - geodetic_to_ecef(r[:, 2:5]), axis=1)
    gsd = float(np.median(pixel_size_m(model, r[:, 0], r[:, 1], r[:, 4])))
    return CheckRow(vp.name, "exact", r.shape[0], *_stats(px), *_stats(m), limit_px, limit_px * gsd)


def _cbers_row(product: Any, limit_px: float) -> CheckRow:
    from solver.sensors.inpe_cbers import corner_check

    c = corner_check(product)
    held = np.array([h["px"] for h in c["held_out"]])
    metres = np.array([h["m"] for h in c["held_out"]])
    if held.size == 0:  # two or three corners: the fit's residuals are all there is
        return CheckRow(f"corners {', '.join(c['corners'])} (the model's fit to them)", "exact", len(c["corners"]),
                        c["fit_rms_px"], c["fit_max_px"], None, None, limit_px, None)
    gsd = float(np.median(metres / np.maximum(held, 1e-12)))
    return CheckRow("corners, each from the other three", "exact", held.size, *_stats(held), *_stats(metres), limit_px,
                    limit_px * gsd)


def job_form_model(product: Any, image_id: str = "S"):  # noqa: ANN201 (solver.gis.model.AdjustedImage)
    """The job composed from ``product`` with its orientation as delivered (module docstring)."""
    from solver.gis.model import load_model
    from solver.sensors.job_fragment import fragment

    m = product.model
    doc = fragment([product], [image_id])
    doc.pop("sensor_metadata")
    fl, fc = np.array([0.1, 0.1, 0.9, 0.9, 0.5]), np.array([0.1, 0.9, 0.9, 0.1, 0.5])
    ground = m.image_to_ground(fl * (m.lines - 1), fc * (m.columns - 1), np.zeros(5))
    points = [{"id": f"check-sensor-{k}", "role": "gcp", "coordinates": [float(v) for v in ground[k]],
               "sigma_m": [CONTROL_SIGMA_M] * 3} for k in range(5)]
    obs = [{"image": image_id, "point": f"check-sensor-{k}", "line": float(fl[k] * (m.lines - 1)),
            "column": float(fc[k] * (m.columns - 1)), "sigma_px": 1.0} for k in range(5)]
    job = {"schema_version": "1.0", "name": "check-sensor", **doc, "points": points, "observations": obs}
    return load_model(job, None).image(image_id), doc


def _job_point_row(image: Any, model: LinescanModel, vp: VendorPoints, limit_px: float) -> CheckRow:
    r = vp.rows
    ecef = geodetic_to_ecef(r[:, 2:5])
    if vp.located_by is not None:  # the vendor's point moved by what the vendor left out (the attitude)
        ecef = ecef + model.image_to_ecef(r[:, 0], r[:, 1], r[:, 4]) - vp.located_by.image_to_ecef(r[:, 0], r[:, 1], r[:, 4])
    line, col, _ = image.ground_to_image(ecef)
    px = np.hypot(line - r[:, 0], col - r[:, 1])
    m = np.linalg.norm(image.image_to_ground(r[:, 0], r[:, 1], r[:, 4]) - ecef, axis=1)
    gsd = float(np.median(pixel_size_m(model, r[:, 0], r[:, 1], r[:, 4])))
    return CheckRow(vp.name, "job form", r.shape[0], *_stats(px), *_stats(m), limit_px, limit_px * gsd)


def _rpc_rows(model: LinescanModel, image: Any, rpc: RPC, name: str, limit_px: float) -> list[CheckRow]:
    from solver.sensors.agreement import image_grid

    L, C, H = image_grid(model, rpc, RPC_GRID, RPC_HEIGHTS)
    gsd = float(np.median(pixel_size_m(model, L[:25], C[:25], H[:25])))
    rows = []
    forms = [("exact", lambda: model.image_to_ground(L, C, H))]
    if image is not None:
        from solver.geometry.geodesy import ecef_to_geodetic

        forms.append(("job form", lambda: ecef_to_geodetic(image.image_to_ground(L, C, H))))
    for label, ground in forms:
        g = ground()
        rl, rc = rpc.project(g[:, 0], g[:, 1], g[:, 2])
        px = np.hypot(rl - L, rc - C)
        rms, mx = _stats(px)
        rows.append(CheckRow(f"vendor RPC ({name})", label, int(L.size), rms, mx, rms * gsd, mx * gsd, limit_px, limit_px * gsd))
    return rows


def _job_grid_row(image: Any, model: LinescanModel, mean_height_m: float, limit_px: float) -> CheckRow:
    n = JOB_GRID
    L, C = (a.ravel() for a in np.meshgrid(np.linspace(0, model.lines - 1, n), np.linspace(0, model.columns - 1, n), indexing="ij"))
    px, metres = [], []
    for dh in JOB_HEIGHTS_M:
        h = np.full(L.size, mean_height_m + dh)
        g = model.image_to_ecef(L, C, h)
        line, col, _ = image.ground_to_image(g)
        px.append(np.hypot(line - L, col - C))
        metres.append(np.linalg.norm(image.image_to_ground(L, C, h) - g, axis=1))
    gsd = float(np.median(pixel_size_m(model, L, C, np.full(L.size, mean_height_m))))
    return CheckRow("the exact model over the image", "job form", int(L.size) * len(JOB_HEIGHTS_M),
                    *_stats(np.concatenate(px)), *_stats(np.concatenate(metres)), limit_px, limit_px * gsd)


def product_rpc(product: Any) -> tuple[RPC | None, str]:
    """The RPC the product carries or names beside itself (None when neither), and its name."""
    if getattr(product, "rpc", None) is not None:
        return product.rpc, "in the metadata file"
    path = getattr(product, "rpc_path", None)
    return (None, path.name) if path is not None else (None, "")


def self_check(product: Any, rpc: RPC | None = None, rpc_name: str = "", job_form: bool = True) -> SelfCheck:
    """The self-check of a product (module docstring). ``rpc``: an RPC to compare with (the
    product's own when None and it has one); ``job_form``: also check the job form (it compiles
    and runs the adjustment's kernels)."""
    from solver.sensors.errors import MetadataError
    from solver.sensors.inpe_cbers import CbersProduct
    from solver.sensors.job_fragment import source

    m = product.model
    out = SelfCheck(product.file, _satellite(product))
    screening = product.warnings if isinstance(product, CbersProduct) else product.screening.messages()
    points, notes = vendor_points(product)
    out.notes = [f"reading: {m}" for m in screening] + notes
    if rpc is None:
        rpc, rpc_name = product_rpc(product)
    image = None
    if isinstance(product, CbersProduct):
        from dataclasses import replace

        from solver.sensors.inpe_cbers import map_grid

        why = map_grid(product)
        if why is not None:  # the record's geometry is checked as the raw image's (FILE#raw)
            out.notes.append(f"{why}: a job needs FILE#raw (measurements in the raw image)")
            product = replace(product, raw_geometry=True)
    if job_form:
        try:
            image, _ = job_form_model(product)
        except MetadataError as exc:  # a product the job cannot express (solver.sensors.job_fragment refuses it)
            out.notes.append(f"no job form: {exc.reason}")
    for vp in points:
        if isinstance(product, CbersProduct):
            out.rows.append(_cbers_row(product, LIMITS_PX["point"]))
        else:
            out.rows.append(_exact_point_row(m, vp, LIMITS_PX["point"]))
        if image is not None:
            out.rows.append(_job_point_row(image, m, vp, LIMITS_PX["point"]))
    if rpc is not None:
        out.rows += _rpc_rows(m, image, rpc, rpc_name or "given", LIMITS_PX["rpc"])
    elif not isinstance(product, CbersProduct):
        out.notes.append("no vendor RPC" + (f" ({rpc_name} is not beside the file)" if rpc_name else "") + ": give one with --rpc")
    if image is not None:
        out.rows.append(_job_grid_row(image, m, source(product).mean_height_m, LIMITS_PX["job"]))
    return out


def _satellite(product: Any) -> str:
    for attr in ("satellite", "mission"):
        if getattr(product, attr, ""):
            name = getattr(product, attr)
            return f"{name} {getattr(product, 'instrument', '')}".strip()
    return ""


def format_table(check: SelfCheck, image_id: str) -> list[str]:
    """The rows as text lines (``pba check-sensor``)."""
    lines = [f"{image_id}: {check.satellite} ({check.file})",
             f"  {'reference':<62} {'model':<9} {'points':>6} {'RMS px':>9} {'max px':>9} {'RMS m':>9} {'max m':>9}  limit"]
    for r in check.rows:
        m = "" if r.rms_m is None else f"{r.rms_m:9.3f} {r.max_m:9.3f}"
        limit = f"{r.limit_px:g} px" + (f" ({r.limit_m:.3g} m)" if r.limit_m is not None else "")
        lines.append(f"  {r.reference:<62} {r.model:<9} {r.points:>6} {r.rms_px:9.3f} {r.max_px:9.3f} {m:>19}  {limit}"
                     + ("" if r.passed else "  ABOVE THE LIMIT"))
    lines += [f"  note: {n}" for n in check.notes]
    return lines
