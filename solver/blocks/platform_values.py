"""Initial values of the images' platform blocks (kind ``image``, :mod:`solver.blocks.platform`).

1. Position coefficients from the image's approximate state at line 0 (ECEF position, velocity,
   and the rotating-frame acceleration of a J2 orbit), converted to each model's frame and time
   variable; or from the job's ``initial`` values.
2. Attitude: the rotation that best aligns the image rays of the control points with their
   object-space directions (Wahba's problem, solved by SVD), converted to (omega, phi, kappa);
   without control on the image, the nominal attitude (:func:`nominal_attitude`): the camera
   pitched by its mounting angle from the platform's own geodetic vertical, its x axis along
   the flight direction. Rates start at zero. Refining the angles (or a whole resection) on
   the control points before the bundle was measured and rejected: it moves each image along
   its weakly determined pitch / along-track-position direction away from the header state, and
   the bundle then needs 51+ instead of 8 (triplet) or 26 (20 triplets) iterations.
3. ``initial`` values given in the job override both (report units).

The kernels (numba) are imported where they are evaluated: validation imports the block kinds
in the API process.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from solver.errors import Problem
from solver.platforms import ANGLES, ELEMENTS, HELD, coef_index
from solver.platforms.kepler import AE_M, GM_M3_S2, J2, OMEGA_RAD_S
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState, ImageState, rows_by_image


def is_kepler(image: ImageState) -> bool:
    """Position from the image's own Earth-fixed state vector (Kepler, J2, orbit-attitude)."""
    return image.model.kind.ecef_state


def angles_from_matrix(m: np.ndarray) -> tuple[float, float, float]:
    """(omega, phi, kappa) in rad of M = Rx(omega) Ry(phi) Rz(kappa)."""
    phi = math.asin(max(-1.0, min(1.0, m[0, 2])))
    kappa = math.atan2(-m[0, 1], m[0, 0])
    omega = math.atan2(-m[1, 2], m[2, 2])
    return omega, phi, kappa


def rotating_frame_acceleration(r: np.ndarray, v: np.ndarray) -> np.ndarray:
    from solver.kernels import gravity_and_gradient

    g, _ = gravity_and_gradient(r, GM_M3_S2, J2, AE_M)
    return g + np.array(
        [OMEGA_RAD_S**2 * r[0] + 2 * OMEGA_RAD_S * v[1], OMEGA_RAD_S**2 * r[1] - 2 * OMEGA_RAD_S * v[0], 0.0]
    )


def _set_position_from_state(img: ImageState, frame, r_ecef: np.ndarray, v_ecef: np.ndarray) -> None:
    c = img.base
    if is_kepler(img):
        for e in range(3):
            c[e * 4] = r_ecef[e]
            c[e * 4 + 1] = v_ecef[e]
        return
    dt_dtau = img.tau_per_line and (img.camera.line_time_s / img.tau_per_line)
    a = rotating_frame_acceleration(r_ecef, v_ecef)
    s = frame.to_lgs(r_ecef)
    v = frame.vector_to_lgs(v_ecef)
    a = frame.vector_to_lgs(a)
    orders = img.model.effective_orders(img.options)
    for e in range(3):
        c[e * 4] = s[e]
        if orders[e] >= 1:
            c[e * 4 + 1] = v[e] * dt_dtau
        if orders[e] >= 2:
            c[e * 4 + 2] = 0.5 * a[e] * dt_dtau**2


def apply_initial(img: ImageState) -> None:
    """Overwrite coefficients with the job's ``initial`` values (report units)."""
    specs = {p.name: p for p in img.model.parameters(img.options)}
    for name, value in img.initial.items():
        spec = specs[name]
        img.base[spec.index] = value / spec.to_report


def _wahba(obj_dirs: np.ndarray, cam_dirs: np.ndarray) -> np.ndarray:
    """Rotation M minimising sum |c_i - M d_i|^2 (unit vectors as rows)."""
    h = obj_dirs.T @ cam_dirs
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def platform_level(frame, r_ecef: np.ndarray) -> np.ndarray:
    """The rotation T (3 x 3, LGS axes) that takes the LGS up to the geodetic up at the platform
    position ``r_ecef`` (ECEF m) by the smallest turn (Rodrigues): the axes of a level frame
    there, as columns in LGS components. The identity on the LGS origin's vertical; 2.7 deg
    away per 300 km from it, 68 deg at 7,500 km."""
    from solver.geometry.geodesy import ecef_to_geodetic, enu_rotation

    lon, lat, _h = ecef_to_geodetic(np.asarray(r_ecef, dtype=float)[None, :])[0]
    up = frame.vector_to_lgs(enu_rotation(math.radians(lon), math.radians(lat))[2])
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(ez, up)
    s, c = float(np.linalg.norm(axis)), float(ez @ up)
    if s < 1e-15:
        return np.eye(3)
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)


def nominal_attitude(img: ImageState, frame, v_ecef: np.ndarray | None, r_ecef: np.ndarray | None = None) -> tuple[float, float, float]:
    """(omega, phi, kappa) in rad of the nominal attitude in the LGS: no roll, the camera's
    mounting pitch, the camera x axis along the flight direction (``v_ecef``, m/s, Earth-fixed).

    With the platform position ``r_ecef`` (ECEF m), the pitch and the heading are
    taken from the platform's own geodetic vertical (:func:`platform_level`), as a satellite
    pointing at its nadir sees: with T that level frame and M_0 the nominal rotation in it,
    ``M = M_0 T^T``. Without, from the LGS vertical, which is right only near the LGS origin: an
    image 1,500 km along a strip would start 13.5 deg off nadir, one 7,500 km away 68 deg (the
    rays then miss the ground and the bundle diverges)."""
    pitch = math.radians(img.camera.mounting_pitch_deg)
    if v_ecef is None:
        return 0.0, pitch, 0.0
    v = frame.vector_to_lgs(v_ecef)
    if r_ecef is None:
        return 0.0, pitch, math.atan2(-v[1], v[0])
    from solver.kernels import rotation_and_derivatives  # the kernels' M(omega, phi, kappa)

    t = platform_level(frame, r_ecef)
    v = t.T @ v  # the velocity in the level frame's axes
    return angles_from_matrix(rotation_and_derivatives(0.0, pitch, math.atan2(-v[1], v[0]))[0] @ t.T)


def initial_platform_values(problem: AdjustmentState, states: dict[int, Any]) -> list[Problem]:
    """Every image's platform parameters (in place): position from its approximate state
    (``states``: image index -> ApproxState or None), attitude by resection on its control (or
    nominal), the job's ``initial`` values over both; the problems that stop it."""
    job = problem.job
    frame = problem.frame
    issues: list[Problem] = []
    seen = _ControlSeen(problem)
    for img, im_doc in zip(problem.images, job.images):
        specs = {p.name: p for p in img.model.parameters(img.options)}
        unknown = sorted(set(im_doc.initial) - set(specs))
        if unknown:
            issues.append(
                Problem(
                    "unknown_parameter",
                    f"image {img.id!r}: model {img.model.name} has no parameter(s) {', '.join(unknown)}",
                    ("images", img.index, "initial"),
                )
            )
            continue
        if not img.model.kind.has_camera:  # an RPC bias: 0, or the job's initial values
            apply_initial(img)
            img.params[:] = img.base[img.free_idx]
            continue
        v_ecef = r_ecef = None
        state = states.get(img.index)  # approx_state or the interpolated ephemeris
        if state is not None:
            r_ecef = np.array(state.position_ecef_m, dtype=float)
            v_ecef = np.array(state.velocity_ecef_m_s, dtype=float)
            if img.model.kind.position_from_image_state:  # pass states: the pass blocks' own initialise
                _set_position_from_state(img, frame, r_ecef, v_ecef)
        elif img.model.kind.position_from_image_state:
            pos_names = {"X0", "Y0", "Z0"}
            if not pos_names <= set(im_doc.initial):
                issues.append(
                    Problem(
                        "no_initial_position",
                        f"image {img.id!r} needs approx_state (position/velocity at line 0), an "
                        "ephemeris covering first_line_time_s, or initial values for its position "
                        "parameters",
                        ("images", img.index, "approx_state"),
                    )
                )
                continue
        # held angles
        held = img.model.held_values_rad(img.options, img.camera.mounting_pitch_deg)
        for e, val in held.items():
            img.base[coef_index(e, 0)] = val
        # user-given position-related values before the attitude resection
        apply_initial(img)
        img.params[:] = img.base[img.free_idx]
        orders = img.model.effective_orders(img.options)
        # a model that holds an angle keeps the LGS vertical: its held angles are LGS values
        levelled = r_ecef is not None and all(orders[ELEMENTS.index(e)] != HELD for e in ANGLES)
        omega, phi, kappa = _attitude_by_resection(problem, img, v_ecef, seen, r_ecef if levelled else None)
        for e, val in zip(ANGLES, (omega, phi, kappa)):
            if orders[ELEMENTS.index(e)] != HELD:
                img.base[coef_index(e, 0)] = val
        if state is not None and state.attitude_deg is not None:
            for e, val in zip(ANGLES, state.attitude_deg):
                if orders[ELEMENTS.index(e)] != HELD:
                    img.base[coef_index(e, 0)] = math.radians(val)
        apply_initial(img)
        img.params[:] = img.base[img.free_idx]
    return issues


class _ControlSeen:
    """Each image's observations of control points (``gcp``; ``known`` also with surveyed
    coordinates), found once for all images."""

    def __init__(self, problem: AdjustmentState):
        obs = problem.obs
        gcp = np.array([p.role == "gcp" for p in problem.points], dtype=bool)
        known = gcp & np.array([p.known_lgs is not None for p in problem.points], dtype=bool)
        self.rows = rows_by_image(obs.img, len(problem.images))
        self.gcp_obs, self.known_obs = gcp[obs.pt], known[obs.pt]

    def gcp(self, image: int) -> np.ndarray:
        r = self.rows[image]
        return r[self.gcp_obs[r]]

    def known(self, image: int) -> np.ndarray:
        r = self.rows[image]
        return r[self.known_obs[r]]


def _attitude_by_resection(problem: AdjustmentState, img: ImageState, v_ecef, seen: _ControlSeen,
                           r_ecef: np.ndarray | None = None) -> tuple[float, float, float]:
    """The image's initial angles: Wahba's rotation on three or more observations of surveyed
    control, else the nominal attitude (levelled at ``r_ecef`` when given)."""
    if img.model.kind.attitude_in_orbital_frame:
        # relative to the orbital frame: nominally zero; without control in the image, the mean of
        # its attitude samples (roll, pitch, yaw in that frame) when the job weights them
        # (options.attitude): from zero, images pointed off nadir would start at nadir and the rays
        # of tie points without control start (nearly) parallel. With control, zero as before: a
        # start that close to the solution can end Ceres' iterations early on its relative step
        # (measured: 0.49 px instead of 0.017 px on a WorldView-2 image with 4 control points).
        # (with an attitude base the angles are a correction to the delivered attitude: zero)
        samples = problem.job.images[img.index].attitude
        controlled = len(seen.gcp(img.index)) > 0
        based = bool(problem.job.images[img.index].attitude_base)
        if samples and JobSettings.of(problem.job).blocks.attitude is not None and not controlled and not based:
            return tuple(float(np.radians(np.mean([getattr(a, f) for a in samples]))) for f in ("roll_deg", "pitch_deg", "yaw_deg"))
        return 0.0, 0.0, 0.0
    obs = problem.obs
    sel = seen.known(img.index)
    if len(sel) < 3:
        return nominal_attitude(img, problem.frame, v_ecef, r_ecef)
    from solver.kernels import platform_state

    coef = img.coef()
    obj = []
    cam = []
    for k in sel:
        oc = obs.oc[k]
        s = platform_state(img.kind, coef, img.kc, oc[0] * oc[8])[0]
        d = problem.points[obs.pt[k]].known_lgs - s
        obj.append(d / np.linalg.norm(d))
        y = (oc[1] - oc[7]) * oc[4] + oc[6]
        c = np.array([oc[5], y, -oc[3]])
        cam.append(c / np.linalg.norm(c))
    m = _wahba(np.array(obj), np.array(cam))
    return angles_from_matrix(m)
