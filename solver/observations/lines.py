"""Straight-line ground control (seed 002): the equivalent planes model and a rigorous model.

A job's ``lines`` (:class:`solver.schema.job.GroundLine`) are object-space straight lines given by two
points, each seen in one or more images either as measured image points (line, column) or as
fitted image-line parameters. Control lines enter the adjustment as image-only residual terms
(:mod:`solver.engine.terms`): they involve the platform parameters of one image and nothing else,
because the object line is held fixed (its survey sigmas are propagated into the weights, see
below). Check lines are only compared with the adjusted orientation (report ``lines``).

Image coordinates. ``x`` is along track (the image line axis, growing with time) and ``y`` across
track (the column axis), as the camera axes x_c, y_c of :mod:`solver.kernels`. Fitted input is
in pixels (x = line, y = column). The equivalent planes model works in a *pseudo-frame* of each
(line, image): the focal-plane coordinates (mm) a frame camera at the line's reference epoch
would measure,

    x = xo + (L - L_r) k        y = yo + (C - c_chip) pixel

with L_r the reference line of the observation (the mean line of its measured points, or of the
projected object line for fitted input), (xo, yo, c_chip) the chip constants of
:mod:`solver.kernels`, and k = pixel (mm per image line): the scene is read as a frame image of
square pixels, as in the paper. L_r and k only define coordinates and are fixed; how far the
scene departs from that frame image (non-square ground pixels, the motion of the perspective
centre, attitude rates) is what the correction below accounts for.

Rigorous model (``options.line_model = "rigorous"``, the default). Each measured image point
m_i = (L_i, C_i) must lie on the exact pushbroom image of the object line: with
Q(s) = P1 + s (P2 - P1) and q(s) its projection by :func:`solver.kernels.project` (each point at
its own line time, the chip of the measured point), the residual is the signed distance

    d_i = n_i . (m_i - q(s_i*)),   s_i* = argmin_s |m_i - q(s)|,   n_i = unit normal of q'(s_i*)

in pixels. By the envelope theorem dd_i/dp = -n_i . dq/dp at fixed s_i* (exact, no
frame-camera approximation and so no correction step). Fitted input: the residual is the fitted
(a, b) minus the (a, b) of the line through the exact pushbroom projections of P1 and P2.

Equivalent planes model (``"equivalent_planes"``, seed 002 eqs 1-4). The plane through the
perspective centre S = S(t_r) and the object line has the normal N = (P2 - P1) x (P1 - S); in
the image (rotation M = M(t_r), object -> camera) it is n = M N = (A, B, C), and the image line
is A x + B y - C f = 0:

    y = a x + b:    a = -A / B,   b = f C / B       (eq 3; chosen when |dy| <= |dx|)
    x = a' y + b':  a' = -B / A,  b' = f C / A      (eq 4; otherwise)

The observed (a, b) come from a least-squares fit of the measured points in the pseudo-frame
(or from the fitted input, transformed), with their covariance.

Pushbroom correction (eqs 5-8). A frame camera at S(t_r) sees the object line where eqs 3-4 say;
the pushbroom scene records each of its points from its own perspective centre, so the measured
line is slightly rotated and shifted (mostly by the shear of a platform whose x axis is not
aligned with its Earth-fixed velocity, e.g. the Earth-rotation skew of a scene taken without
yaw steering). The correction is da = a2 - a1, db = b2 - b1 with (a1, b1) from eqs 3-4 (the
frame projection at t_r) and (a2, b2) the line through the exact pushbroom projections of P1
and P2 in the pseudo-frame (eqs 5-6), both at the current orientation; the model then fits
(a - da, b - db). ``options.line_correction``: ``iterated`` (default) recomputes da, db from
the solution after each solve and solves again until no whitened residual changes by more than
:data:`solver.observations.family.REFRESH_TOL` (at most ``MAX_REFRESHES`` times); at that fixed point the model is
exact (a = a2), the frame geometry only serving as the Jacobian. ``initial`` computes them once
from the initial orientation (the paper's procedure, with ephemeris-based EOP); ``none`` omits
them (seed 002 Table 6).

Weights. Image points have ``sigma_px`` on line and column (the perpendicular distance has the
same sigma); fitted input its (sigma_a, sigma_b, correlation). Endpoint survey sigmas (east,
north, up, taken along the LGS axes) are propagated through the model: the residuals of one
(line, image) get the covariance C = C_obs + J_P diag(sigma^2) J_P^T and are whitened by the
inverse Cholesky factor of C. For a line seen in one image this is the linearised equivalent of
estimating the endpoints as weighted parameters; for a line seen in several images the
correlation it induces between the images is neglected. J_P is refreshed with the corrections.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from solver.errors import JobError, Problem
from solver.geometry.geodesy import UnknownCRSError, parse_crs
from solver.kernels import layout as lt  # the line-term descriptor words (no kernel: numba stays unloaded)
from solver.observations.family import (
    REFRESH_TOL,
    Count,
    FamilyDefaults,
    GroupSpec,
    Labelled,
    ReportContext,
    per_row_groups,
)
from solver.observations.line_data import (
    FORM_NAMES,
    FORM_X,
    FORM_Y,
    GroundLineState,
    LineImage,
    LineSet,
    line_point_constants,
    lines_ecef,
    on_a_chip,
)
from solver.platforms import ANGLES, ELEMENTS, HELD
from solver.schema.settings import JobSettings

ANDERSON_MEMORY = 6  # refreshes remembered by the Anderson mixing of the corrections
MIN_IMAGE_LENGTH_PX = 1.0  # a line whose image is shorter is edge-on / projects to a point
MIN_ENDPOINT_DISTANCE_M = 0.01
MIN_POINT_SPAN_PX = 1.0


def _project_endpoint(img, coef, p: np.ndarray, line_guess: float) -> tuple[bool, float, float, np.ndarray]:
    """Exact projection of LGS point ``p`` with the chip it falls on (found by re-projecting)."""
    from solver.kernels import project  # numba (here and below): validation never loads the kernels

    cam = img.camera
    oc = line_point_constants(img, line_guess, (cam.columns - 1) / 2.0)
    ok, line, col = False, line_guess, oc[1]
    for _ in range(3):
        ok, line, col, *_ = project(img.kind, coef, img.kc, p, oc, False)
        new = line_point_constants(img, line if np.isfinite(line) else line_guess, col if np.isfinite(col) else oc[1])
        if new[5] == oc[5] and new[6] == oc[6] and new[7] == oc[7]:
            oc = new
            break
        oc = new
    oc[0] = line if np.isfinite(line) else line_guess
    return bool(ok), float(line), float(col), oc


def _fit_points(x: np.ndarray, y: np.ndarray, sx: float, sy: float) -> tuple[int, np.ndarray, np.ndarray]:
    """Form, (a, b) and covariance of the least-squares line through points with sigmas sx, sy."""
    xy = np.column_stack([x, y])
    c = xy - xy.mean(axis=0)
    direction = np.linalg.svd(c, full_matrices=False)[2][0] if len(x) > 1 else np.array([1.0, 0.0])
    form = FORM_Y if abs(direction[0]) >= abs(direction[1]) else FORM_X
    u, v, su, sv = (x, y, sx, sy) if form == FORM_Y else (y, x, sy, sx)
    a_mat = np.column_stack([u, np.ones_like(u)])
    ab = np.linalg.lstsq(a_mat, v, rcond=None)[0]
    var = sv**2 + ab[0] ** 2 * su**2  # error of v - a u
    cov = var * np.linalg.inv(a_mat.T @ a_mat)
    return form, ab, cov


def _to_pseudo_frame(form: int, ab: np.ndarray, cov: np.ndarray, mp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-coordinate line parameters -> pseudo-frame (same form), with the covariance.

    ``mp`` = (x0, L_r, kx, y0, c, ky): x = x0 + (L - L_r) kx, y = y0 + (C - c) ky.
    """
    x0, lr, kx, y0, cc, ky = mp
    a, b = ab
    if form == FORM_Y:  # C = a L + b
        out = np.array([a * ky / kx, y0 + ky * (b - cc) + a * ky * (lr - x0 / kx)])
        jac = np.array([[ky / kx, 0.0], [ky * (lr - x0 / kx), ky]])
    else:  # L = a C + b
        out = np.array([a * kx / ky, x0 + kx * (b - lr) + a * kx * (cc - y0 / ky)])
        jac = np.array([[kx / ky, 0.0], [kx * (cc - y0 / ky), kx]])
    return out, jac @ cov @ jac.T


def _switch_form(ab: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """y = a x + b <-> x = a' y + b' (a' = 1/a, b' = -b/a), with the covariance."""
    a, b = ab
    jac = np.array([[-1.0 / a**2, 0.0], [b / a**2, -1.0 / a]])
    return np.array([1.0 / a, -b / a]), jac @ cov @ jac.T


def start(problem) -> None:
    """Reference epochs, pseudo-frame observations and the first corrections/weights, from the
    current (initial) orientation. Called once, lazily, by :func:`line_terms`."""
    ls: LineSet = problem.lines
    if ls is None or ls.started:
        return
    issues: list[Problem] = []
    for li in ls.images:
        gl = ls.lines[li.line]
        img = problem.images[li.image]
        cam = img.camera
        coef = img.coef()
        k = ls.k_mm.setdefault(li.image, float(cam.pixel_mm))
        guess = float(li.points[:, 0].mean()) if li.n_points else (cam.lines - 1) / 2.0
        ok1, l1, c1, oc1 = _project_endpoint(img, coef, gl.p1, guess)
        ok2, l2, c2, oc2 = _project_endpoint(img, coef, gl.p2, guess)
        li.end_ocs = np.ascontiguousarray([oc1, oc2])
        length = math.hypot(l2 - l1, c2 - c1)
        if not (ok1 and ok2) or not np.isfinite(length) or length < MIN_IMAGE_LENGTH_PX:
            issues.append(
                Problem(
                    "line_edge_on",
                    f"line {gl.id!r} projects to a point in image {img.id!r} "
                    f"({length:.2g} px long with the initial orientation): it is (nearly) parallel to "
                    "the viewing direction or too short, so it cannot constrain the orientation",
                    ("lines", gl.index, "observations", li.k),
                )
            )
            continue
        if li.n_points:
            li.ref_line = float(li.points[:, 0].mean())
            mid = li.points[np.argmin(np.abs(li.points[:, 0] - li.ref_line))]
            li.ref_oc = line_point_constants(img, li.ref_line, float(mid[1]))
            # pseudo-frame coordinates of the measured points, each with its own chip
            x = li.ocs[:, 5] + (li.points[:, 0] - li.ref_line) * k
            y = li.ocs[:, 6] + (li.points[:, 1] - li.ocs[:, 7]) * cam.pixel_mm
            li.form, li.ab_obs, li.ab_cov = _fit_points(x, y, li.sigma_px * k, li.sigma_px * cam.pixel_mm)
            # closest-point parameters: projection on the chord of the projected endpoints
            d = np.array([l2 - l1, c2 - c1])
            li.s = np.ascontiguousarray(((li.points - np.array([l1, c1])) @ d) / (d @ d))
        else:
            li.ref_line = 0.5 * (l1 + l2)
            li.ref_oc = line_point_constants(img, li.ref_line, 0.5 * (c1 + c2))
            form, ab, cov = li.fitted  # type: ignore[misc]
            mp = np.array([li.ref_oc[5], li.ref_line, k, li.ref_oc[6], li.ref_oc[7], cam.pixel_mm])
            ab_m, cov_m = _to_pseudo_frame(form, ab, cov, mp)
            dx, dy = (l2 - l1) * k, (c2 - c1) * cam.pixel_mm
            want = FORM_Y if abs(dx) >= abs(dy) else FORM_X
            if want != form:
                ab_m, cov_m = _switch_form(ab_m, cov_m)
            li.form, li.ab_obs, li.ab_cov = want, ab_m, cov_m
    if issues:
        raise JobError(issues)
    ls.started = True
    for li in ls.images:
        _refresh_one(problem, li, initial=True)


def _pseudo_maps(problem, li: LineImage) -> tuple[np.ndarray, np.ndarray]:
    img = problem.images[li.image]
    k = problem.lines.k_mm[li.image]
    px = img.camera.pixel_mm
    return tuple(np.array([oc[5], li.ref_line, k, oc[6], oc[7], px]) for oc in li.end_ocs)  # type: ignore[return-value]


_PIXEL_MAP = np.array(lt.PIXEL_MAP)


def _endpoint_cov(gl: GroundLineState) -> np.ndarray | None:
    if gl.sigma_m is None:
        return None
    return np.diag(np.concatenate([gl.sigma_m, gl.sigma_m]) ** 2)


def _whitening(cov: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.linalg.inv(np.linalg.cholesky(cov)))


def _refresh_one(problem, li: LineImage, initial: bool = False) -> None:
    """Recompute the correction (equivalent planes) and the weights at the current orientation."""
    from solver.kernels.lines import line_distances, planes_model, pushbroom_line

    ls: LineSet = problem.lines
    gl = ls.lines[li.line]
    img = problem.images[li.image]
    coef = img.coef()
    cp = _endpoint_cov(gl)
    if ls.model == "equivalent_planes":
        tau = li.ref_line * img.tau_per_line
        ab1, _jc, jp = planes_model(img.kind, coef, img.kc, gl.p1, gl.p2, tau, img.camera.focal_mm, li.form, cp is not None)
        if ls.correction == "iterated" or (ls.correction == "initial" and initial):
            mp1, mp2 = _pseudo_maps(problem, li)
            ok, ab2, _c, _p = pushbroom_line(img.kind, coef, img.kc, gl.p1, gl.p2, li.end_ocs[0], li.end_ocs[1], mp1, mp2, li.form, False)
            if ok and np.all(np.isfinite(ab2)):
                li.correction = ab2 - ab1
        cov = li.ab_cov + (jp @ cp @ jp.T if cp is not None else 0.0)
    elif li.n_points:
        cov = li.sigma_px**2 * np.eye(li.n_points)
        if cp is not None:
            _ok, _d, _jc, jp = line_distances(img.kind, coef, img.kc, gl.p1, gl.p2, li.ocs, li.s, True)
            cov = cov + jp @ cp @ jp.T
    else:
        form, _ab, fcov = li.fitted  # type: ignore[misc]
        cov = fcov
        if cp is not None:
            _ok, _ab2, _jc, jp = pushbroom_line(
                img.kind, coef, img.kc, gl.p1, gl.p2, li.end_ocs[0], li.end_ocs[1], _PIXEL_MAP, _PIXEL_MAP, form, True
            )
            cov = cov + jp @ cp @ jp.T
    li.whiten = _whitening(np.atleast_2d(cov))


# ---- residual terms ---------------------------------------------------------------------------


class LineTerm:
    """Whitened residuals of one control line in one image, wrt the image's free parameters.

    Rigorous, measured points: n rows, the signed image distances (px) of the points from the
    exact pushbroom image of the object line. Rigorous, fitted input: 2 rows, fitted (a, b) minus
    those of the projected line (pixels). Equivalent planes: 2 rows, observed (a, b) minus the
    correction minus eqs 3-4 (pseudo-frame). All multiplied by the whitening matrix W.
    """

    def __init__(self, problem, li: LineImage):
        ls: LineSet = problem.lines
        self.li = li
        self.gl = ls.lines[li.line]
        self.img = problem.images[li.image]
        self.image_index = li.image
        self.model = ls.model
        if self.model == "equivalent_planes" or not li.n_points:
            self.n_residuals = 2
        else:
            self.n_residuals = li.n_points
        if self.model == "equivalent_planes":
            self.tau = li.ref_line * self.img.tau_per_line

    def raw(self, params: np.ndarray, want_jac: bool = True) -> tuple[np.ndarray, np.ndarray, bool]:
        """Unwhitened residuals (observed - model) and their Jacobian wrt the free parameters."""
        from solver.kernels import assemble
        from solver.kernels.lines import line_distances, planes_model, pushbroom_line

        img, gl, li = self.img, self.gl, self.li
        coef = assemble(img.base, img.free_idx, np.asarray(params, dtype=float))
        if self.model == "equivalent_planes":
            ab, jc, _jp = planes_model(img.kind, coef, img.kc, gl.p1, gl.p2, self.tau, img.camera.focal_mm, li.form, want_jac)
            return li.ab_obs - li.correction - ab, -jc[:, img.free_idx], True
        if li.n_points:
            ok, d, jc, _jp = line_distances(img.kind, coef, img.kc, gl.p1, gl.p2, li.ocs, li.s, want_jac)
            return d, jc[:, img.free_idx], bool(ok)
        form, ab_obs, _cov = li.fitted  # type: ignore[misc]
        ok, ab, jc, _jp = pushbroom_line(
            img.kind, coef, img.kc, gl.p1, gl.p2, li.end_ocs[0], li.end_ocs[1], _PIXEL_MAP, _PIXEL_MAP, form, want_jac
        )
        return ab_obs - ab, -jc[:, img.free_idx], bool(ok)

    def compiled_form(self) -> tuple[str, np.ndarray, tuple[np.ndarray, ...]]:
        """The compiled path's form: ``line_term_callback`` of :mod:`solver.kernels.callbacks`
        (the same kernels as :meth:`raw` and the same whitening as :meth:`evaluate`), its
        descriptor (words ``LT_*`` of :mod:`solver.kernels.layout`) and the arrays it points
        into. The closest points' parameters are the term's own array, updated in place as here."""
        img, gl, li = self.img, self.gl, self.li
        f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
        kc, base, p1, p2 = f64(img.kc), f64(img.base), f64(gl.p1), f64(gl.p2)
        free = np.ascontiguousarray(img.free_idx, dtype=np.int64)
        w = f64(np.atleast_2d(li.whiten))
        scal = np.array([getattr(self, "tau", 0.0), img.camera.focal_mm, float(li.form)])
        ocs = s = np.zeros(1)
        if self.model == "equivalent_planes":
            mode, target = lt.LT_PLANES, f64(li.ab_obs - li.correction)
        elif li.n_points:
            mode, target = lt.LT_DISTANCES, np.zeros(2)
            li.s = f64(li.s)  # the term's own array: the callback updates it as raw() does
            ocs, s = f64(li.ocs), li.s
        else:
            form, ab_obs, _cov = li.fitted  # type: ignore[misc]
            mode, target, ocs = lt.LT_FITTED, f64(ab_obs), f64(np.stack([li.end_ocs[0], li.end_ocs[1]]))
            scal[2] = float(form)
        desc = np.zeros(lt.LT_WORDS, dtype=np.int64)
        desc[lt.LT_MODE], desc[lt.LT_KIND], desc[lt.LT_NFREE], desc[lt.LT_M] = mode, img.kind, len(free), self.n_residuals
        desc[lt.LT_KC], desc[lt.LT_KC_LEN] = kc.ctypes.data, len(kc)
        arrays = (kc, base, free, p1, p2, w, target, ocs, s, scal)
        for word, a in zip((lt.LT_BASE, lt.LT_FREE, lt.LT_P1, lt.LT_P2, lt.LT_W, lt.LT_TARGET, lt.LT_OCS, lt.LT_S, lt.LT_SCAL), arrays[1:]):
            desc[word] = a.ctypes.data
        return "line_term_callback", desc, arrays

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, j, ok = self.raw(params)
        w = self.li.whiten
        res = w @ r
        if not ok:
            res = np.full_like(res, np.nan)
        return res, w @ j


def line_terms(problem) -> list[LineTerm]:
    """The residual terms of every control line observation (starting the line state if needed)."""
    ls: LineSet | None = getattr(problem, "lines", None)
    if ls is None or not ls.images:
        return []
    start(problem)
    return [LineTerm(problem, li) for li in ls.active()]


def _anderson(ls: LineSet, used: np.ndarray, computed: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Next corrections by Anderson mixing of the fixed-point map c -> corrections(solution(c)).

    ``used`` are the corrections of the last solve, ``computed`` those its solution gives; the
    plain fixed-point step would take ``computed``. With the last :data:`ANDERSON_MEMORY`
    pairs, the step minimises the linearised mismatch ||W (g - c)|| over their span (Walker &
    Ni 2011, "type II", no damping). It converges where the plain iteration is slow or unstable:
    in a weak geometry the corrections react to the solution as strongly as the frame-camera
    model does, and the plain map can expand (factor 1.25 per refresh in a 12-line ON2 job).
    """
    hist = ls.anderson
    hist.append((used.copy(), computed.copy()))
    del hist[: -ANDERSON_MEMORY - 1]
    if len(hist) < 2:
        return computed
    f = np.array([weights * (g - c) for c, g in hist])  # weighted residuals, one row per refresh
    g_all = np.array([g for _c, g in hist])
    d_f = np.diff(f, axis=0).T
    d_g = np.diff(g_all, axis=0).T
    gamma = np.linalg.lstsq(d_f, f[-1], rcond=1e-10)[0]
    proposal = computed - d_g @ gamma
    return proposal if np.all(np.isfinite(proposal)) else computed


def refresh_lines(problem) -> float:
    """Recompute corrections and weights at the current orientation.

    Returns the largest change (in sigmas) this makes to any whitened residual at the current
    parameters; 0 when nothing depends on the orientation. In the ``iterated`` equivalent planes
    model the next corrections come from :func:`_anderson` (plain fixed-point iteration the first
    time).
    """
    ls: LineSet | None = getattr(problem, "lines", None)
    if ls is None or not ls.started:
        return 0.0
    active = ls.active()
    terms = [LineTerm(problem, li) for li in active]
    before = [t.evaluate(problem.images[li.image].params)[0] for t, li in zip(terms, active)]
    used = np.concatenate([li.correction for li in active]) if active else np.zeros(0)
    for li in active:
        _refresh_one(problem, li)
    if ls.model == "equivalent_planes" and ls.correction == "iterated" and active:
        computed = np.concatenate([li.correction for li in active])
        weights = np.concatenate([np.abs(np.diag(li.whiten)) for li in active])
        nxt = _anderson(ls, used, computed, weights)
        for k, li in enumerate(active):
            li.correction = nxt[2 * k : 2 * k + 2].copy()
    change = 0.0
    for t, li, b in zip(terms, active, before):
        after = t.evaluate(problem.images[li.image].params)[0]
        if np.all(np.isfinite(b)) and np.all(np.isfinite(after)):
            change = max(change, float(np.max(np.abs(after - b))))
        else:
            change = math.inf
    ls.refresh_changes.append(change)
    return change


# ---- validation -------------------------------------------------------------------------------


def _viewing_check(gl_ecef: np.ndarray, im, cam) -> tuple[float, float] | None:
    """(angle between the line and the viewing direction in degrees, approximate image length
    in px) from the image's approximate state, or None when it cannot be estimated."""
    st = im.approx_state
    if st is None or cam is None or cam.focal_mm is None or cam.pixel_mm is None:
        return None
    s0 = np.array(st.position_ecef_m, dtype=float)
    v = np.array(st.velocity_ecef_m_s, dtype=float)
    speed = float(np.linalg.norm(v))
    if speed == 0.0:
        return None
    vh = v / speed
    mid = gl_ecef.mean(axis=0)
    height = float(np.linalg.norm(s0) - np.linalg.norm(mid))
    # the epoch at which the camera (pitched by its mounting angle) looks at the midpoint
    along = float((mid - s0) @ vh) - height * math.tan(math.radians(cam.mounting_pitch_deg))
    s = s0 + vh * along
    view = mid - s
    rng = float(np.linalg.norm(view))
    u = gl_ecef[1] - gl_ecef[0]
    length = float(np.linalg.norm(u))
    sin_a = float(np.linalg.norm(np.cross(u / length, view / rng)))
    angle = math.degrees(math.asin(min(1.0, sin_a)))
    return angle, length * sin_a / rng * cam.focal_mm / cam.pixel_mm


def _line_endpoints(job, gl, loc: tuple, converted: dict[str, np.ndarray]) -> tuple[list[Problem], np.ndarray | None]:
    """The line's CRS and endpoints: (problems, ECEF endpoints or None when unusable)."""
    problems: list[Problem] = []
    ecef = None
    try:
        parse_crs(gl.crs or job.crs)
        ecef = converted.get(gl.id)
    except UnknownCRSError as exc:
        problems.append(_crs_problem(exc, loc, gl.crs is not None))
    if ecef is not None and float(np.linalg.norm(ecef[1] - ecef[0])) < MIN_ENDPOINT_DISTANCE_M:
        problems.append(
            Problem(
                "line_endpoints_coincide",
                f"line {gl.id!r}: its two points coincide (less than {MIN_ENDPOINT_DISTANCE_M} m apart), "
                "so they do not define a line",
                loc + ("endpoints",),
            )
        )
        ecef = None
    return problems, ecef


def _line_form_problem(gl, o, oloc: tuple) -> Problem | None:
    """An image of a line gives either two or more image points or fitted parameters."""
    npts = len(o.points)
    if o.fitted is not None and npts:
        return Problem(
            "line_observation_ambiguous",
            f"line {gl.id!r} in image {o.image!r}: give either image points or fitted parameters, not both",
            oloc,
        )
    if o.fitted is None and npts == 0:
        return Problem(
            "line_observation_empty",
            f"line {gl.id!r} in image {o.image!r}: no image points and no fitted parameters",
            oloc + ("points",),
        )
    if o.fitted is None and npts == 1:
        return Problem(
            "line_single_point",
            f"line {gl.id!r} in image {o.image!r} has a single image point: a line needs at least two",
            oloc + ("points",),
        )
    return None


def _line_point_problems(gl, o, oloc: tuple, cam) -> list[Problem]:
    """Measured image points that do not define a line or lie outside the image (or on no chip)."""
    problems: list[Problem] = []
    pts = np.array([[q.line, q.column] for q in o.points], dtype=float)
    span = float(np.max(np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2)))
    if span < MIN_POINT_SPAN_PX:
        problems.append(
            Problem(
                "line_image_points_coincide",
                f"line {gl.id!r} in image {o.image!r}: its image points span {span:.2g} px, "
                f"less than {MIN_POINT_SPAN_PX} px, so they do not define a line",
                oloc + ("points",),
            )
        )
    if cam is not None and cam.lines is not None and cam.columns is not None:
        for q, pt in enumerate(o.points):
            if not (-0.5 <= pt.line <= cam.lines - 0.5 and on_a_chip(cam, pt.column)):
                problems.append(
                    Problem(
                        "outside_image",
                        f"line {gl.id!r} in image {o.image!r}: point {q} ({pt.line}, {pt.column}) is "
                        f"outside the image (0..{cam.lines - 1}, 0..{cam.columns - 1}) or on no CCD chip",
                        oloc + ("points", q),
                    )
                )
                break
    return problems


def _edge_on_problem(gl, o, oloc: tuple, image, cam, ecef: np.ndarray) -> Problem | None:
    """A line the image sees (nearly) edge-on: it would project to less than MIN_IMAGE_LENGTH_PX."""
    view = _viewing_check(ecef, image, cam)
    if view is None or view[1] >= MIN_IMAGE_LENGTH_PX:
        return None
    angle, length_px = view
    why = (
        f"it is within {angle:.2g} deg of the viewing direction"
        if angle < 10.0
        else "its two points are too close together to be told apart"
    )
    return Problem(
        "line_edge_on",
        f"line {gl.id!r} is seen edge-on in image {o.image!r}: it would project to about "
        f"{length_px:.2g} px ({why}), so it cannot constrain the orientation",
        oloc,
        {"angle_deg": angle, "image_length_px": length_px},
    )


def collect_line_problems(job, cameras: dict, images: dict) -> tuple[list[Problem], dict[str, Any]]:
    """Problems of the job's lines, and counts: ``n_observations`` (control line equations for
    the chosen model), ``per_image`` (control line observations per image id), ``n_control``."""
    problems: list[Problem] = []
    counts: dict[str, Any] = {"n_observations": 0, "per_image": {}, "n_control": 0}
    seen_ids: dict[str, int] = {}
    rigorous = JobSettings.of(job).blocks.line_model == "rigorous"
    converted = lines_ecef(job)
    if job.lines and (getattr(job.options, "self_calibration", None) is not None or any(
        any(float(v) != 0.0 for v in (cam.iop or {}).values() if isinstance(v, (int, float)))
        for cam in cameras.values()
    )):
        problems.append(
            Problem(
                "lines_with_interior_orientation",
                "straight-line observations are not yet combined with interior orientation (camera "
                "iop values or options.self_calibration): the line models use the nominal camera",
                ("lines",),
            )
        )
    for j, gl in enumerate(job.lines):
        loc = ("lines", j)
        if gl.id in seen_ids:
            problems.append(Problem("duplicate_id", f"line id {gl.id!r} is used more than once", loc + ("id",)))
        seen_ids[gl.id] = j
        endpoint_issues, ecef = _line_endpoints(job, gl, loc, converted)
        problems += endpoint_issues
        used_images: set[str] = set()
        for k, o in enumerate(gl.observations):
            oloc = loc + ("observations", k)
            if o.image not in images:
                problems.append(
                    Problem("unknown_image", f"line {gl.id!r} observation {k} refers to unknown image {o.image!r}", oloc + ("image",))
                )
                continue
            if o.image in used_images:
                problems.append(
                    Problem("duplicate_line_observation", f"line {gl.id!r} is observed twice in image {o.image!r}", oloc)
                )
                continue
            used_images.add(o.image)
            form = _line_form_problem(gl, o, oloc)
            if form is not None:
                problems.append(form)
                continue
            cam = cameras.get(images[o.image].camera)
            issues = _line_point_problems(gl, o, oloc, cam) if o.points else []
            edge = _edge_on_problem(gl, o, oloc, images[o.image], cam, ecef) if ecef is not None else None
            issues += [edge] if edge is not None else []
            problems += issues
            if issues or gl.role != "control":
                continue
            npts = len(o.points)
            counts["n_observations"] += npts if (rigorous and npts) else 2
            counts["per_image"][o.image] = counts["per_image"].get(o.image, 0) + 1
            counts["n_control"] += 1
    return problems, counts


def _crs_problem(exc: Exception, loc: tuple, own: bool) -> Problem:
    return Problem("unknown_crs", str(exc), loc + ("crs",) if own else ("crs",))


# ---- report -----------------------------------------------------------------------------------


def _distances_now(problem, li: LineImage) -> np.ndarray:
    """Rigorous image distances (px) of the measured points at the current orientation; for
    fitted input, the distances of the projected endpoints from the fitted image line."""
    from solver.kernels import project
    from solver.kernels.lines import line_distances

    ls: LineSet = problem.lines
    gl = ls.lines[li.line]
    img = problem.images[li.image]
    coef = img.coef()
    if li.n_points:
        s = li.s.copy() if li.s.shape[0] == li.n_points else np.zeros(li.n_points)
        _ok, d, _jc, _jp = line_distances(img.kind, coef, img.kc, gl.p1, gl.p2, li.ocs, s, False)
        return d
    form, ab, _cov = li.fitted  # type: ignore[misc]
    out = []
    for p, oc in zip((gl.p1, gl.p2), li.end_ocs):
        _ok, ln, cl, *_ = project(img.kind, coef, img.kc, p, oc, False)
        a, b = ab
        if form == FORM_Y:  # C = a L + b
            out.append((cl - a * ln - b) / math.hypot(1.0, a))
        else:
            out.append((ln - a * cl - b) / math.hypot(1.0, a))
    return np.array(out)


def lines_report(problem, s_inv: np.ndarray | None, img_col: np.ndarray | None, sigma0_apriori: float) -> dict[str, Any]:
    """The report's ``lines`` section (docs/report-contract.md)."""
    ls: LineSet | None = getattr(problem, "lines", None)
    blocks = JobSettings.of(problem.job).blocks
    out: dict[str, Any] = {
        "model": blocks.line_model,
        "correction": blocks.line_correction if blocks.line_model == "equivalent_planes" else None,
        "refresh_changes": [],
        "resolves": 0,
        "items": [],
        "rmse_px": {"control": None, "check": None},
        "warnings": [],
    }
    if ls is None or not ls.lines:
        return out
    start(problem)
    out["refresh_changes"] = [float(c) for c in ls.refresh_changes]
    out["resolves"] = sum(1 for c in ls.refresh_changes if c > REFRESH_TOL)
    if ls.refresh_changes and ls.refresh_changes[-1] > REFRESH_TOL:
        out["warnings"].append(
            f"the line corrections did not settle in {len(ls.refresh_changes)} refreshes (last change "
            f"{ls.refresh_changes[-1]:.3g} sigma): the equivalent planes solution is not a fixed point"
        )
    if ls.model == "equivalent_planes" and ls.active():
        loose = sorted(
            {
                img.id
                for img in problem.images
                if any(img.model.effective_orders(img.options)[ELEMENTS.index(e)] != HELD for e in ANGLES[:2])
            }
        )
        if loose:
            out["warnings"].append(
                "the equivalent planes line model is used with omega/phi estimated (images "
                + ", ".join(loose)
                + "): its frame-camera Jacobian separates pitch from along-track position where the "
                "pushbroom geometry does not, so their estimates and sigmas are unreliable; hold "
                "omega/phi (MT8, ON/MT12 models) or use the rigorous line model"
            )
    by_line: dict[int, list[LineImage]] = {}
    for li in ls.images:
        by_line.setdefault(li.line, []).append(li)
    all_d: dict[str, list[float]] = {"control": [], "check": []}
    for gl in ls.lines:
        images = []
        for li in by_line.get(gl.index, []):
            img = problem.images[li.image]
            d = _distances_now(problem, li)
            all_d[gl.role].extend(d.tolist())
            item: dict[str, Any] = {
                "image": img.id,
                "input": "points" if li.n_points else "fitted",
                "n_points": li.n_points,
                "sigma_px": li.sigma_px if li.n_points else None,
                "distances_px": [float(x) for x in d],
                "rmse_px": float(np.sqrt(np.mean(d**2))) if len(d) else None,
                "max_abs_px": float(np.max(np.abs(d))) if len(d) else None,
                "residuals": None,
                "standardized": None,
                "form": None,
                "correction": None,
            }
            if gl.role == "control":
                term = LineTerm(problem, li)
                raw, jac, _ok = term.raw(img.params)
                item["residuals"] = [float(x) for x in raw]
                if ls.model == "equivalent_planes":
                    item["form"] = FORM_NAMES[li.form]
                    item["residual_units"] = ["1", "mm"]
                    item["correction"] = [float(x) for x in li.correction]
                elif li.n_points:
                    item["residual_units"] = ["px"] * li.n_points
                else:
                    item["form"] = FORM_NAMES[li.fitted[0]]  # type: ignore[index]
                    item["residual_units"] = ["1", "px"]
                if s_inv is not None and img_col is not None:
                    c0 = int(img_col[li.image])
                    block = s_inv[c0 : c0 + img.nfree, c0 : c0 + img.nfree]
                    wr = li.whiten @ raw
                    wj = li.whiten @ jac
                    h = np.einsum("ij,jk,ik->i", wj, block, wj)
                    red = 1.0 - h
                    item["standardized"] = [
                        float(r / (sigma0_apriori * math.sqrt(q))) if q > 1e-9 else None for r, q in zip(wr, red)
                    ]
            images.append(item)
        out["items"].append(
            {
                "id": gl.id,
                "role": gl.role,
                "endpoints_lgs_m": [[float(x) for x in gl.p1], [float(x) for x in gl.p2]],
                "images": images,
            }
        )
    for role, vals in all_d.items():
        if vals:
            out["rmse_px"][role] = float(np.sqrt(np.mean(np.square(vals))))
    return out


# ---- the family: validation, terms, tests, report, removal and flags -------------------------


def without_line_points(job, removals: list[tuple]) -> tuple[Any, list[dict]]:
    """``job`` without the line image points ``("line_point", line id, image id, k)`` (k: the
    index in that image's ``points``; None: the fitted image line as a whole); a line image left
    with fewer than two points goes as a whole (collateral)."""
    drop: dict[tuple[str, str], set] = {}
    for r in removals:
        if r[0] == "line_point":
            drop.setdefault((r[1], r[2]), set()).add(r[3])
    if not drop:
        return job, []
    lines, collateral = [], []
    for gl in job.lines:
        obs = []
        for lo in gl.observations:
            gone = drop.get((gl.id, lo.image), set())
            if None in gone:
                continue
            if gone:
                pts = [q for k, q in enumerate(lo.points) if k not in gone]
                if len(pts) < 2:
                    collateral.append({"kind": "line_point", "line": gl.id, "image": lo.image, "point": None,
                                       "units": "px", "components": ["distance"]})
                    continue
                lo = lo.model_copy(update={"points": pts})
            obs.append(lo)
        lines.append(gl.model_copy(update={"observations": obs}))
    return job.model_copy(update={"lines": lines}), collateral


def line_point_coordinates(job, line: str, image: str, k: int | None) -> dict[str, float | None]:
    """The measured image coordinates (px) of point ``k`` of ``line`` in ``image`` in ``job``
    (the job at the time of the removal, whose indices the removal used); ``None`` for a line
    image removed whole."""
    if k is not None:
        for gl in job.lines:
            if gl.id != line:
                continue
            for lo in gl.observations:
                if lo.image == image and 0 <= k < len(lo.points):
                    q = lo.points[k]
                    return {"line": float(q.line), "column": float(q.column)}
    return {"line": None, "column": None}


class LineFamily(FamilyDefaults):
    """Straight-line control as an observation family: a measured line image point (rigorous
    model) or a fitted image line / an equivalent-planes line image is one test
    (``line_point``), removable; report section ``lines`` (flag: ``items[].rejected``)."""

    name = "lines"

    def check(self, job) -> tuple[list[Problem], Count]:
        problems, counts = collect_line_problems(job, {c.id: c for c in job.cameras}, {im.id: im for im in job.images})
        datum = frozenset({"control"}) if counts["n_control"] else frozenset()
        return problems, Count(n_observations=counts["n_observations"], per_image=counts["per_image"], datum=datum)

    def terms(self, problem) -> list[Labelled]:
        return [Labelled(self, t, "image", t.image_index) for t in line_terms(problem)]

    def refresh(self, problem) -> float:
        return refresh_lines(problem)

    def groups(self, problem, labelled: Labelled) -> list[GroupSpec]:
        term: LineTerm = labelled.term
        label = {"image": problem.images[term.image_index].id, "line": term.gl.id}
        removal = lambda lab: ("line_point", lab["line"], lab["image"], lab.get("point"))  # noqa: E731
        m = term.n_residuals
        if m == 2 and (term.model == "equivalent_planes" or not term.li.n_points):  # one (a, b) pair
            return per_row_groups("line_point", m, 2, {**label, "point": None}, None, np.ones(m), "whitened", ["a", "b"],
                                  1.0, removal)
        return per_row_groups("line_point", m, 1, label, [{"point": j} for j in range(m)], np.full(m, float(term.li.sigma_px)),
                              "px", ["distance"], 1.0, removal)

    def report(self, problem, ctx: ReportContext) -> dict[str, Any]:
        section = lines_report(problem, ctx.covariance, ctx.layout.img_col if ctx.layout is not None else None, ctx.sigma0_apriori)
        ctx.warnings += section["warnings"]
        return {"lines": section}

    def without(self, job, removals: list[tuple]) -> tuple[Any, list[dict[str, Any]]]:
        return without_line_points(job, removals)

    def removal_details(self, job, removal: tuple) -> dict[str, Any]:
        """The removed point's measured pixels (its index shifts with later removals)."""
        return {"measured": line_point_coordinates(job, removal[1], removal[2], removal[3])}

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        """``lines.items[].rejected``: ``[{"image", "line", "column"}]`` for a measured line image
        point (image coordinates in pixels, as measured), ``{"image", "line": null, "column":
        null}`` for a line image removed whole (a fitted image line, or the last point of a line
        image, ``collateral``)."""
        items = {it["id"]: it for it in (report.get("lines") or {}).get("items") or []}
        for it in items.values():
            it["rejected"] = []
        for r in removed:
            if r["kind"] == "line_point" and r.get("line") in items:
                where = r.get("measured") or {"line": None, "column": None}
                items[r["line"]]["rejected"].append({"image": r.get("image"), **where})


FAMILY = LineFamily()
