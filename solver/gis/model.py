"""The adjusted rigorous model of a finished job, rebuilt from the job document and its report.

The job is validated, assembled and initialised exactly as the adjustment did it
(:func:`solver.adjust.prepare`: the same LGS, Kepler constants, chips and held values), then
every estimated value is taken from the report: the images' platform parameters
(``images[].parameters``, report units divided by ``to_report``), the cameras' interior
orientation (``cameras[].parameters``) and the passes' states (``passes[].parameters``). The
projection is the solver's own (:func:`solver.kernels._eval_record`, the kernel of the
residuals), so a point projects exactly where the adjustment put it.

Image convention (the solver's, the job's and the report's): ``line`` and ``column`` in
pixels with the origin at the **centre** of the top-left pixel; line 0 is the image's first
line (``first_line_time_s``), columns follow the camera's chip layout
(:mod:`solver.geometry.sensor`). GDAL's RPC transformer uses pixel corners instead
(:mod:`solver.gis.rpc_io`).

Ground coordinates are ECEF metres (EPSG:4978) at this interface; heights are ellipsoidal.

RPC images (issue 17: an image with ``rpc`` and a model RPC-SHIFT, RPC-DRIFT or RPC-AFFINE,
no camera) are :class:`solver.gis.rpc_image.RpcImage`: the delivered RPC plus the report's bias
``a0 .. b_column``, with the same ``ground_to_image`` / ``image_to_ground`` interface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic
from solver.geometry.sensor import camera_chip, chip_index_of_column
from solver.gis.rpc_image import RpcImage, rpc_image
from solver.kernels.layout import OBS_REC, REC_CAM_SLOT, REC_CAMERA, REC_CHIP, REC_CHIP_LEN, REC_IMAGE, REC_IMG_SLOT, REC_OC, REC_PASS_SLOT
from solver.schema.job import Job, load_job
from solver.state import AdjustmentState, ImageState


class ModelMismatch(ValueError):
    """The report does not belong to the job (another image set, model or parameter list)."""


HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (lon_deg, lat_deg) -> ellipsoidal height m


def _apply_report(problem: AdjustmentState, report: dict[str, Any]) -> None:
    """Set every estimated value of ``problem`` to the report's (in place)."""
    from solver.blocks import registry as blocks

    if report.get("kind") != "adjustment":
        raise ModelMismatch("the report is not that of an adjustment (kind 'adjustment'); a comparison report has one report per model")
    by_id = {e["id"]: e for e in report.get("images", [])}
    for img in problem.images:
        entry = by_id.get(img.id)
        if entry is None:
            raise ModelMismatch(f"image {img.id!r} of the job is not in the report")
        if entry.get("model") != img.model.name:
            raise ModelMismatch(f"image {img.id!r}: the report's model is {entry.get('model')!r}, the job's {img.model.name!r}")
        values = {p["name"]: p["value"] for p in entry["parameters"] if p.get("estimated")}
        coef = img.coef()
        for spec in img.model.parameters(img.options):
            if spec.name not in values:
                raise ModelMismatch(f"image {img.id!r}: parameter {spec.name!r} missing from the report")
            coef[spec.index] = values[spec.name] / spec.to_report
        img.params[:] = coef[img.free_idx]
        img.base[:] = coef
    cams = {e["id"]: e for e in report.get("cameras") or []}
    for st in problem.cameras:
        entry = cams.get(st.id)
        if entry is None:
            continue
        vals = st.values()
        for p in entry["parameters"]:
            if p["name"] in st.names:
                vals[st.names.index(p["name"])] = p["value"]
        st.base[:] = vals
        st.params[:] = vals[st.free_idx]
    passes = {e["id"]: e for e in report.get("passes") or []}
    for ps in problem.passes:
        entry = passes.get(ps.id)
        if entry is None:
            raise ModelMismatch(f"pass {ps.id!r} of the job is not in the report")
        ps.params[:] = [p["value"] for p in entry["parameters"]]
    blocks.refresh(problem)


@dataclass
class AdjustedImage:
    """One adjusted image: ground <-> image with the adjusted rigorous model."""

    model: "AdjustedModel"
    image: ImageState

    @property
    def id(self) -> str:
        return self.image.id

    @property
    def lines(self) -> int:
        return int(self.image.camera.lines or 0)

    @property
    def columns(self) -> int:
        return int(self.image.camera.columns or 0)

    @property
    def kind(self) -> str:
        return self.image.model.name

    @property
    def n_chips(self) -> int:
        return max(len(self.image.camera.chips), 1)

    def chip_range(self, k: int) -> tuple[float, float]:
        """First and last column (pixel centres) of chip ``k`` inside the delivered image."""
        cam = self.image.camera
        if not cam.chips:
            return 0.0, float(self.columns - 1)
        c = cam.chips[k]
        return float(max(c.first_column, 0)), float(min(c.first_column + c.columns - 1, self.columns - 1))

    # ---- constants of one (chip) record ------------------------------------------------
    def _chip_constants(self, k: int) -> tuple[float, float, float]:
        cam = self.image.camera
        if not cam.chips:
            return 0.0, 0.0, (self.columns - 1) / 2.0
        c = cam.chips[k]
        return c.dx_mm, c.dy_mm, c.first_column + (c.columns - 1) / 2.0

    def _record(self, k: int, line: float, column: float) -> np.ndarray:
        cam = self.image.camera
        pm = self.model.problem
        cs = pm.cameras[self.model.camera_index[cam.id]]
        dx, dy, centre = self._chip_constants(k)
        x0, y0 = cam.principal_point_mm
        r = np.zeros(OBS_REC)
        r[REC_IMAGE] = self.image.index
        r[REC_CAMERA] = cs.index
        r[REC_IMG_SLOT] = -1
        r[REC_CAM_SLOT] = -1
        r[REC_CHIP] = k
        r[REC_CHIP_LEN] = cs.chip_len_mm[k] if cs.chip_len_mm else 0.0
        r[REC_OC : REC_OC + 9] = (line, column, 1.0, cam.focal_mm, cam.pixel_mm, dx - x0, dy - y0, centre, self.image.tau_per_line)
        r[REC_PASS_SLOT] = -1
        return r

    # ---- ground to image ---------------------------------------------------------------
    def project_chip(self, ecef: np.ndarray, k: int, line_guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(line, column, converged) of ECEF points (n, 3) on chip ``k`` (its line of pixels
        extended as far as needed: the column may fall outside the chip)."""
        from solver.kernels import _eval_record  # numba (here and in rays): loaded by the first transform, not by importing

        lgs = self.model.problem.frame.to_lgs(np.atleast_2d(ecef))
        n = len(lgs)
        line = np.empty(n)
        col = np.empty(n)
        ok = np.zeros(n, dtype=bool)
        lo, hi = self.chip_range(k)
        guess = np.full(n, (self.lines - 1) / 2.0) if line_guess is None else np.asarray(line_guess, float)
        img_tab, cam_tab = self.model.tables
        params = self.model.no_params
        for i in range(n):
            rec = self._record(k, float(guess[i]) if np.isfinite(guess[i]) else (self.lines - 1) / 2.0, (lo + hi) / 2.0)
            out = _eval_record(rec, img_tab, cam_tab, lgs[i].copy(), params, False)
            ok[i], line[i], col[i] = bool(out[0]), float(out[1]), float(out[2])
        return line, col, ok

    def ground_to_image(self, ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(line, column, chip index) of ECEF points (n, 3); chip -1 where no chip's column
        range holds the point (then line and column are those of the nearest chip)."""
        ecef = np.atleast_2d(np.asarray(ecef, float))
        cam = self.image.camera
        if not cam.chips:
            line, col, ok = self.project_chip(ecef, 0)
            return np.where(ok, line, np.nan), np.where(ok, col, np.nan), np.where(ok, 0, -1)
        lines, cols, margins, owns = [], [], [], []
        guess = None
        firsts = [c.first_column for c in cam.chips]
        widths = [c.columns for c in cam.chips]
        for k, c in enumerate(cam.chips):
            line, col, ok = self.project_chip(ecef, k, guess)
            guess = line
            margin = np.minimum(col - (c.first_column - 0.5), (c.first_column + c.columns - 0.5) - col)
            own = ok & (margin >= 0) & (chip_index_of_column(firsts, widths, col) == k)
            lines.append(np.where(ok, line, np.nan))
            cols.append(np.where(ok, col, np.nan))
            margins.append(np.where(ok, margin, -np.inf))
            owns.append(own)
        L, C, M, O = np.array(lines), np.array(cols), np.array(margins), np.array(owns)
        best = np.where(O.any(axis=0), np.argmax(np.where(O, M, -np.inf), axis=0), np.argmax(M, axis=0))
        idx = np.arange(len(ecef))
        chip = np.where(O[best, idx], best, -1)
        return L[best, idx], C[best, idx], chip

    # ---- image to ground ---------------------------------------------------------------
    def rays(self, line: np.ndarray, column: np.ndarray, chip: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Perspective centres and unit directions (ECEF) of image points (pixel centres);
        the chip follows the column (:mod:`solver.geometry.sensor`) unless ``chip`` is given."""
        from solver.kernels import ray, ray_cam

        line = np.atleast_1d(np.asarray(line, float))
        column = np.atleast_1d(np.asarray(column, float))
        frame = self.model.problem.frame
        img = self.image
        coef = img.coef()
        cs = self.model.problem.cameras[self.model.camera_index[img.camera.id]]
        iop = cs.values()
        s = np.empty((len(line), 3))
        d = np.empty((len(line), 3))
        ids = [c.id for c in img.camera.chips] or ["1"]
        for i in range(len(line)):
            if chip is None:
                try:
                    k = ids.index(camera_chip(img.camera, float(column[i]))[0])
                except KeyError:
                    s[i] = d[i] = np.nan
                    continue
            else:
                k = chip
            rec = self._record(k, float(line[i]), float(column[i]))
            oc = rec[REC_OC : REC_OC + 9].copy()
            if cs.has_iop:
                si, di = ray_cam(img.kind, coef, img.kc, oc, iop, k, rec[REC_CHIP_LEN])
            else:
                si, di = ray(img.kind, coef, img.kc, oc)
            s[i] = frame.to_ecef(si)
            d[i] = frame.vector_to_ecef(di)
        return s, d

    def image_to_ground(
        self,
        line: np.ndarray,
        column: np.ndarray,
        height_m: np.ndarray | float | None = None,
        height_fn: HeightFn | None = None,
        chip: int | None = None,
    ) -> np.ndarray:
        """ECEF points (n, 3) where the rays of image points meet the ellipsoidal height
        ``height_m`` or the surface ``height_fn(lon_deg, lat_deg)`` (a DEM)."""
        s, d = self.rays(line, column, chip)
        return intersect_height(s, d, height_m, height_fn)


def intersect_height(origin: np.ndarray, direction: np.ndarray, height_m: np.ndarray | float | None, height_fn: HeightFn | None) -> np.ndarray:
    """Newton iteration along rays ``origin + s direction`` (ECEF) for the point of ellipsoidal
    height ``height_m`` (or ``height_fn`` of its longitude and latitude), to 1e-6 m in height."""
    if (height_m is None) == (height_fn is None):
        raise ValueError("give exactly one of height_m and height_fn")
    n = len(origin)
    good = np.all(np.isfinite(origin), axis=1) & np.all(np.isfinite(direction), axis=1)
    out = np.full((n, 3), np.nan)
    if not good.any():
        return out
    o, d = origin[good], direction[good]
    target0 = None if height_m is None else np.broadcast_to(np.asarray(height_m, float), (n,))[good]
    up = o / np.linalg.norm(o, axis=1, keepdims=True)
    s = (np.linalg.norm(o, axis=1) - 6.371e6) / np.maximum(-np.einsum("ni,ni->n", d, up), 0.05)
    for _ in range(60):
        p = o + s[:, None] * d
        llh = ecef_to_geodetic(p)
        target = target0 if height_fn is None else np.asarray(height_fn(llh[:, 0], llh[:, 1]), float)
        f = llh[:, 2] - target
        lon, lat = np.radians(llh[:, 0]), np.radians(llh[:, 1])
        normal = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
        s = s - f / np.einsum("ni,ni->n", d, normal)
        if np.all(np.abs(f[np.isfinite(f)]) < 1e-6):
            break
    out[good] = o + s[:, None] * d
    return out


class AdjustedModel:
    """Every image of a finished job with its adjusted orientation (see the module docstring)."""

    def __init__(self, job: Job | dict[str, Any] | str | bytes, report: dict[str, Any] | None):
        """``report`` None: the job's own orientation, the one the adjustment starts from (its
        attitude fitted to the job's weighted attitude samples where it has some: for a job from
        vendor metadata, the orientation as delivered; :mod:`solver.engine.initialize`)."""
        from solver.adjust import prepare
        from solver.engine.packed_tables import camera_table, image_table

        self.job = job if isinstance(job, Job) else load_job(job)
        self.report = report
        self.problem = prepare(self.job)
        if report is not None:
            _apply_report(self.problem, report)
        frame = (report or {}).get("frames", {}).get("lgs", {})
        if frame.get("origin_ecef_m") is not None:
            gap = float(np.linalg.norm(np.asarray(frame["origin_ecef_m"]) - self.problem.frame.origin_ecef_m))
            if gap > 1e-3:
                raise ModelMismatch(f"the report's local frame is {gap:.3g} m from the job's: the report is not this job's")
        self.camera_index = {c.id: c.index for c in self.problem.cameras}
        self.tables = (image_table(self.problem), camera_table(self.problem))
        self.refresh_tables = lambda: setattr(self, "tables", (image_table(self.problem), camera_table(self.problem)))
        self.no_params = np.zeros((1, 1))
        rpc_entries = rpc_image_entries(self.job)
        reported = {e["id"]: e for e in (report or {}).get("images", [])}
        self._images: dict[str, AdjustedImage | RpcImage] = {
            im.id: rpc_image(rpc_entries[im.id], reported.get(im.id)) if im.id in rpc_entries else AdjustedImage(self, im)
            for im in self.problem.images
        }

    @property
    def image_ids(self) -> list[str]:
        return list(self._images)

    def image(self, image_id: str) -> "AdjustedImage | RpcImage":
        try:
            return self._images[image_id]
        except KeyError:
            raise KeyError(f"no image {image_id!r} in the job (images: {', '.join(self._images)})") from None

    def height_range_m(self, margin_m: float = 100.0) -> tuple[float, float]:
        """Ellipsoidal height range of the job's known and adjusted points, widened by
        ``margin_m`` on both sides (at least 2 x margin wide)."""
        pts = [p.xyz for p in self.problem.points if np.all(np.isfinite(p.xyz))]
        if not pts:
            return -margin_m, margin_m
        h = ecef_to_geodetic(self.problem.frame.to_ecef(np.array(pts)))[:, 2]
        return float(math.floor(h.min() - margin_m)), float(math.ceil(h.max() + margin_m))


def rpc_image_entries(job: Job) -> dict[str, dict[str, Any]]:
    """``{id: {"id", "rpc", "model"}}`` of the job's RPC images (those with ``rpc``), as plain data."""
    out: dict[str, dict[str, Any]] = {}
    for img in job.images:
        rpc = getattr(img, "rpc", None)
        if rpc is None:
            continue
        if hasattr(rpc, "model_dump"):
            rpc = rpc.model_dump(mode="json", exclude_none=True)
        model = getattr(img, "model", None)
        name = getattr(model, "name", None) or (model.get("name") if isinstance(model, dict) else None)
        out[img.id] = {"id": img.id, "rpc": dict(rpc), "model": {"name": name}}
    return out


def load_model(job: Job | dict[str, Any] | str | bytes, report: dict[str, Any] | None) -> AdjustedModel:
    """The adjusted model of ``job`` with the values of ``report`` (raises :class:`ModelMismatch`);
    without a report, the job's own (delivered) orientation."""
    return AdjustedModel(job, report)
