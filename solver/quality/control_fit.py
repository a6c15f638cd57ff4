"""Control that does not belong, found before solving: control points whose image measurements
are far from where the orientation the job starts from puts them.

For every observation of a control point (role ``gcp``) the point's surveyed coordinates are
projected with the initial orientation (:func:`solver.engine.initialize.initialise`: the
ephemeris and attitude samples as the job weights them, or the header state) and compared with
the measurement:

- **far beyond the stated uncertainty**: for an image whose orientation is stated (weighted
  states: ``options.ephemeris`` or ``approx_state`` sigmas, *and* weighted attitude samples:
  ``options.attitude``) the offset is compared with its predicted size, in pixels,
  ``sqrt((f / (p r))^2 (s_pos^2 + s_gcp^2) + (f / p)^2 (s_att^2 + s_bias^2) + s_px^2)`` (``f / p``
  the focal length over the pixel pitch, ``r`` the range to the point, ``s_att`` the largest of
  the three angle sigmas, radians); beyond :data:`FAR_SIGMAS` times that and
  :data:`MIN_FAR_PX` pixels it does not belong;
- **far outside the image**: a point whose projection lies more than :data:`OUTSIDE_FRACTION`
  of the image's size beyond its lines or columns does not belong.

Only images whose orientation is stated are judged: one whose orientation comes from the
control itself (no weighted states and attitude: the initial attitude is a resection on those
very points, and with one or two points it may put anything anywhere) is not, and there the
adjustment's tests must find a set that does not belong.

The points are reported by name, grouped per image with their median offset ("image 'S': these
43 control points G01, G02, ... are projected 5,721 columns to the right of and 358 lines below
where they were measured (scatter 6.3 px; stated uncertainty 3.2 px; 2 fall outside the image):
another image's points?"). The job is refused (:class:`solver.errors.JobError`, code
``control_does_not_belong``: a 422 problem document, ``pba run`` exits 2) when a point projects
far outside its image, or when the far offsets are at least :data:`GROUP_MIN` points and half
the image's control observations: a set that does not belong, not a blunder. Fewer far points
are named in the report's warnings and left to data snooping, which tests each observation.
``options.control_check`` ``warn`` adjusts anyway in every case, naming them in the warnings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver.errors import Problem
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState

FAR_SIGMAS = 20.0  # an offset beyond this many predicted sigmas ...
MIN_FAR_PX = 50.0  # ... and this many pixels does not belong
OUTSIDE_FRACTION = 0.5  # a projection beyond the image by this fraction of its lines or columns does not belong
GROUP_SCATTER = 0.2  # points whose offsets scatter less than this fraction of their median offset move together
GROUP_MIN = 3  # far offsets of this many points (and half the image's control) refuse the job


@dataclass
class Misfit:
    """The control observations of one image that do not belong."""

    image: str
    image_index: int
    points: list[str]
    offsets_px: np.ndarray  # (k, 2) predicted - measured, line and column
    outside: np.ndarray  # (k,) bool: projected far outside the image
    sigma_px: float | None  # the stated uncertainty (median over the points), None when not stated
    of_control: int  # control observations of the image
    details: list[dict] = field(default_factory=list)

    @property
    def refused(self) -> bool:
        """Whether the job is refused for them (module docstring): a point projected far outside
        the image, or far offsets of at least :data:`GROUP_MIN` points and half the image's
        control; fewer far offsets are blunders for data snooping, named in the warnings."""
        k = len(self.points)
        return bool(self.outside.any()) or (k >= GROUP_MIN and k >= 0.5 * self.of_control)

    def sentence(self) -> str:
        k = len(self.points)
        med = np.median(self.offsets_px, axis=0)
        spread = float(np.sqrt(np.mean(np.sum((self.offsets_px - med) ** 2, axis=1)))) if k > 1 else 0.0
        names = ", ".join(self.points[:12]) + (f" and {k - 12} more" if k > 12 else "")
        together = k > 1 and spread < GROUP_SCATTER * float(np.hypot(*med))
        facts = [f"scatter {spread:.1f} px" if together else (f"median offset; scatter {spread:.0f} px" if k > 1 else "")]
        if self.sigma_px is not None:
            facts.append(f"stated uncertainty {self.sigma_px:.1f} px")
        if self.outside.any():
            facts.append(f"{int(self.outside.sum())} fall outside the image")
        said = "; ".join(f for f in facts if f)
        guess = "another image's points?" if together and k >= max(3, self.of_control // 2) else "blunders, or another image's points?"
        who = f"these {k} control points {names} are" if k > 1 else f"control point {names} is"
        return (f"image {self.image!r}: {who} projected {_side(med[1], 'columns')} and {_side(med[0], 'lines')} where "
                f"{'they were' if k > 1 else 'it was'} measured" + (f" ({said})" if said else "") + f": {guess}")


def _side(value: float, unit: str) -> str:
    """``5,721 columns to the right of`` / ``358 lines below`` (image axes: lines down, columns right)."""
    if not np.isfinite(value):
        return f"nowhere near ({unit})"
    if unit == "lines":
        return f"{abs(value):,.0f} lines {'above' if value < 0 else 'below'}"
    return f"{abs(value):,.0f} columns to the {'left' if value < 0 else 'right'} of"


def _stated_sigmas(problem: AdjustmentState) -> dict[int, tuple[float, float, float] | None]:
    """Per image: (position m, attitude rad, bias rad) sigmas of a stated orientation, or None."""
    job = problem.job
    blocks = JobSettings.of(job).blocks
    eph, att = blocks.ephemeris, blocks.attitude
    out: dict[int, tuple[float, float, float] | None] = {}
    for k, im in enumerate(job.images):
        pos = None
        if im.ephemeris and eph is not None and eph.sigma_position_m is not None:
            pos = eph.sigma_position_m
        elif im.approx_state is not None and im.approx_state.sigma_position_m is not None:
            pos = im.approx_state.sigma_position_m
        if pos is None or not im.attitude or att is None:
            out[k] = None
            continue
        bias = max(att.bias_sigma_deg) if att.bias_sigma_deg is not None else 0.0
        out[k] = (float(pos), float(np.radians(max(att.sigma_deg))), float(np.radians(bias)))
    return out


def control_misfits(problem: AdjustmentState) -> list[Misfit]:
    """The control observations that do not belong (module docstring), per image, at the
    problem's current (initial) values."""
    from solver.engine.packed_tables import current_tables, records
    from solver.kernels import _eval_record, platform_state

    obs = problem.obs
    pts = problem.points
    rows = np.array([r for r in range(len(obs.pt)) if pts[obs.pt[r]].role == "gcp" and pts[obs.pt[r]].known_lgs is not None], int)
    if rows.size == 0:
        return []
    img_tab, cam_tab, _, _ = current_tables(problem)
    rec = records(problem, rows)
    no_params = np.zeros((1, 1))
    stated = _stated_sigmas(problem)
    found: dict[int, list[tuple[int, np.ndarray, bool, float | None]]] = {}
    counts: dict[int, int] = {}
    for i, r in enumerate(rows):
        img = problem.images[obs.img[r]]
        counts[img.index] = counts.get(img.index, 0) + 1
        if img.camera is None or stated.get(img.index) is None:
            # RPC images: their bias priors say how far they may be; an orientation that is not
            # stated comes from a resection on these very points (module docstring)
            continue
        p = pts[obs.pt[r]]
        ok, line, col = _eval_record(rec[i], img_tab, cam_tab, p.known_lgs.astype(float).copy(), no_params, False)[:3]
        measured = obs.oc[r, :2]
        offset = np.array([line - measured[0], col - measured[1]]) if ok else np.array([np.inf, np.inf])
        lines, columns = float(img.camera.lines or 0), float(img.camera.columns or 0)
        outside = bool(not ok or (lines and columns and (
            line < -OUTSIDE_FRACTION * lines or line > (1 + OUTSIDE_FRACTION) * lines
            or col < -OUTSIDE_FRACTION * columns or col > (1 + OUTSIDE_FRACTION) * columns)))
        sigma = None
        s = stated.get(img.index)
        if s is not None:
            pos = platform_state(img.kind, img.coef(), img.kc, obs.oc[r, 0] * obs.oc[r, 8])[0]
            rng = float(np.linalg.norm(p.known_lgs - pos))
            scale = img.camera.focal_mm / img.camera.pixel_mm
            gcp = float(np.max(p.sigma_m)) if p.sigma_m is not None else 0.0
            sigma = float(np.sqrt((scale / rng) ** 2 * (s[0] ** 2 + gcp**2) + scale**2 * (s[1] ** 2 + s[2] ** 2) + obs.oc[r, 2] ** 2))
        far = sigma is not None and np.hypot(*offset) > max(FAR_SIGMAS * sigma, MIN_FAR_PX)
        if outside or far:
            found.setdefault(img.index, []).append((int(r), offset, outside, sigma))
    out = []
    for index, items in found.items():
        img = problem.images[index]
        sig = [x[3] for x in items if x[3] is not None]
        misfit = Misfit(img.id, index, [pts[obs.pt[r]].id for r, *_ in items], np.array([x[1] for x in items]),
                        np.array([x[2] for x in items]), float(np.median(sig)) if sig else None, counts[index])
        misfit.details = [{"point": pts[obs.pt[r]].id, "offset_line_px": float(o[0]) if np.isfinite(o[0]) else None,
                           "offset_column_px": float(o[1]) if np.isfinite(o[1]) else None, "outside_image": bool(out_),
                           "stated_sigma_px": s_} for r, o, out_, s_ in items]
        out.append(misfit)
    return out


def control_problems(misfits: list[Misfit]) -> list[Problem]:
    """One problem per image with control that does not belong (code ``control_does_not_belong``)."""
    return [Problem("control_does_not_belong",
                    m.sentence() + " Remove them, or set options.control_check to \"warn\" to adjust anyway.",
                    ("images", m.image_index), {"image": m.image, "points": m.details}) for m in misfits]
