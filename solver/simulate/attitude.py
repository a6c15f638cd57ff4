"""Platform attitude and camera mounting, as rotation matrices ``camera_from_ecef``.

Frames (all axes expressed in ECEF components; a matrix's rows are the axes of the frame):

- orbit frame (a, n, u): u = r / |r| (radial, up), n = unit(r x v_inertial) (orbit normal),
  a = n x u (along track), with ``v_inertial = v_ecef + Omega x r``;
- yaw-steered platform frame: the orbit frame turned about u by the yaw-steering angle
  psi = atan2(v_ecef . n, v_ecef . a), so that the platform x axis follows the ground track
  (Earth-relative velocity) and the CCD (y axis) stays across it;
- body frame: the platform frame turned by the small attitude errors (roll about x, pitch about
  y, yaw about z; active rotation by the vector roll*x + pitch*y + yaw*z), each a polynomial
  drift plus an optional sinusoidal jitter;
- camera frame (x_c along track in the flight direction, z_c away from the scene, y_c = z_c x
  x_c): the body frame pitched by the mounting angle theta (forward camera +23.8 deg looks ahead):
  x_c = cos(theta) x_b + sin(theta) z_b, y_c = y_b, z_c = cos(theta) z_b - sin(theta) x_b,
  so the boresight -z_c = -cos(theta) z_b + sin(theta) x_b.

A point P with perspective centre S at time t has camera coordinates ``M(t) (P - S(t))`` with
``M = camera_from_ecef(t)``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from solver.simulate.orbit import Orbit


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rotation_from_vector(phi: np.ndarray) -> np.ndarray:
    """Active rotation matrices exp([phi]x) for rotation vectors (n, 3) -> (n, 3, 3) (Rodrigues)."""
    phi = np.atleast_2d(phi)
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-12
    safe = np.where(small, 1.0, theta)
    k = phi / safe[:, None]
    kx = np.zeros((len(phi), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -k[:, 2], k[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = k[:, 2], -k[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -k[:, 1], k[:, 0]
    s = np.where(small, 0.0, np.sin(theta))[:, None, None]
    c = np.where(small, 0.0, 1.0 - np.cos(theta))[:, None, None]
    return np.eye(3)[None] + s * kx + c * (kx @ kx)


def model_attitude_angles(phi: np.ndarray) -> np.ndarray:
    """The simulator's attitude errors (n, 3) as the orbit-attitude models' roll, pitch, yaw (rad).

    The body frame here is the yaw-steered frame F turned actively by the rotation vector phi
    (frame components), i.e. body rows B = exp([phi]x)^T F; the models write B = Rx(roll)
    Ry(pitch) Rz(yaw) R_orbit with R_orbit = F (docs/models.md section 10). So
    Rx Ry Rz = exp([phi]x)^T, decomposed exactly by :func:`opk_from_matrix` (to first order
    the angles are -phi).
    """
    return np.array([opk_from_matrix(r.T) for r in rotation_from_vector(phi)]).reshape(-1, 3)


@dataclass(frozen=True)
class AttitudeModel:
    """Attitude errors of the platform about the yaw-steered orbit frame.

    Each of roll, pitch, yaw (rad) is ``bias + rate (t - t_ref) + accel (t - t_ref)^2 +
    jitter_amplitude sin(2 pi jitter_frequency (t - t_ref) + jitter_phase)``.
    """

    yaw_steering: bool = True
    t_ref_s: float = 0.0
    bias_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rate_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_rad_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    jitter_amplitude_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    jitter_frequency_hz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    jitter_phase_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        bias_rad: float = 2e-4,
        rate_rad_s: tuple[float, float, float] = (1e-6, 1e-6, 1e-5),
        accel_rad_s2: float = 1e-8,
        jitter_rad: float = 0.0,
        jitter_hz: float = 0.5,
        t_ref_s: float = 0.0,
    ) -> "AttitudeModel":
        """A smooth random attitude: normal coefficients with the given standard deviations.

        ``rate_rad_s`` is per axis (roll, pitch, yaw): the default lets yaw drift at ~1e-5 rad/s
        and roll/pitch ten times less, as a three-axis-stabilised platform whose roll and pitch
        are held tighter than yaw.
        """

        def draw(s) -> tuple[float, float, float]:
            sig = np.broadcast_to(np.asarray(s, dtype=float), (3,))
            return tuple(float(x) for x in rng.normal(0.0, 1.0, 3) * sig)

        jit = jitter_rad > 0
        return cls(
            t_ref_s=t_ref_s,
            bias_rad=draw(bias_rad),
            rate_rad_s=draw(rate_rad_s),
            accel_rad_s2=draw(accel_rad_s2),
            jitter_amplitude_rad=draw(jitter_rad) if jit else (0.0, 0.0, 0.0),
            jitter_frequency_hz=(jitter_hz, 1.3 * jitter_hz, 0.7 * jitter_hz) if jit else (0.0, 0.0, 0.0),
            jitter_phase_rad=tuple(float(x) for x in rng.uniform(0, 2 * np.pi, 3)) if jit else (0.0, 0.0, 0.0),
        )

    def angles(self, t_s: np.ndarray) -> np.ndarray:
        """(roll, pitch, yaw) in radians at times ``t_s`` (n,) -> (n, 3)."""
        dt = np.atleast_1d(t_s)[:, None] - self.t_ref_s
        out = np.asarray(self.bias_rad) + np.asarray(self.rate_rad_s) * dt + np.asarray(self.accel_rad_s2) * dt**2
        amp = np.asarray(self.jitter_amplitude_rad)
        if np.any(amp != 0):
            w = 2 * np.pi * np.asarray(self.jitter_frequency_hz)
            out = out + amp * np.sin(w * dt + np.asarray(self.jitter_phase_rad))
        return out

    def to_dict(self) -> dict:
        return asdict(self)


def orbit_frame(orbit: Orbit, r_ecef: np.ndarray, v_ecef: np.ndarray) -> np.ndarray:
    """Orbit frames (n, 3, 3), rows (a, n, u), from ECEF states (inertial velocity inside)."""
    v_in = v_ecef + np.cross(orbit.earth.omega_vec, r_ecef)
    u = _unit(r_ecef)
    n = _unit(np.cross(r_ecef, v_in))
    a = np.cross(n, u)
    return np.stack([a, n, u], axis=1)


def yaw_steering_angle(frame: np.ndarray, v_ecef: np.ndarray) -> np.ndarray:
    """Yaw-steering angle (rad, about u) aligning the along-track axis with the ground track."""
    return np.arctan2(np.einsum("ni,ni->n", v_ecef, frame[:, 1]), np.einsum("ni,ni->n", v_ecef, frame[:, 0]))


@dataclass(frozen=True)
class Platform:
    """An orbit with its attitude law: gives perspective-centre states and camera rotations."""

    orbit: Orbit
    attitude: AttitudeModel = field(default_factory=AttitudeModel)

    def body_from_ecef(self, t_s: np.ndarray) -> np.ndarray:
        """Body frames (n, 3, 3) (rows: body x, y, z in ECEF) at times ``t_s``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        r, v = self.orbit.state(t)
        return self._body(t, r, v)

    def _body(self, t: np.ndarray, r: np.ndarray, v: np.ndarray) -> np.ndarray:
        frame = orbit_frame(self.orbit, r, v)
        if self.attitude.yaw_steering:
            psi = yaw_steering_angle(frame, v)
            c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
            a, n, u = frame[:, 0], frame[:, 1], frame[:, 2]
            frame = np.stack([c * a + s * n, -s * a + c * n, u], axis=1)
        ang = self.attitude.angles(t)
        if np.any(ang != 0):
            rot_vec = np.einsum("nk,nki->ni", ang, frame)  # roll*x + pitch*y + yaw*z in ECEF
            rot = rotation_from_vector(rot_vec)
            frame = np.einsum("nij,nkj->nki", rot, frame)  # rotate each axis
        return frame

    def camera_from_ecef(self, t_s: np.ndarray, mounting_pitch_deg: float) -> np.ndarray:
        """Camera frames (n, 3, 3): rows x_c, y_c, z_c in ECEF components (see module doc)."""
        return self.camera_frames(t_s, mounting_pitch_deg)[2]

    def camera_frames(
        self, t_s: np.ndarray, mounting_pitch_deg: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Perspective-centre position (n, 3) m, velocity (n, 3) m/s (ECEF) and camera frames."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        r, v = self.orbit.state(t)
        b = self._body(t, r, v)
        th = np.radians(mounting_pitch_deg)
        c, s = np.cos(th), np.sin(th)
        m = np.stack([c * b[:, 0] + s * b[:, 2], b[:, 1], c * b[:, 2] - s * b[:, 0]], axis=1)
        return r, v, m


def rx(a: float) -> np.ndarray:
    """Active (right-handed) rotation about x by ``a`` rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a: float) -> np.ndarray:
    """Active (right-handed) rotation about y by ``a`` rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a: float) -> np.ndarray:
    """Active (right-handed) rotation about z by ``a`` rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def opk_from_matrix(m: np.ndarray) -> tuple[float, float, float]:
    """(omega, phi, kappa) in radians with ``m = Rx(omega) Ry(phi) Rz(kappa)`` (active matrices).

    This is the solver's convention (:mod:`solver.kernels`): ``m`` maps object-frame (LGS)
    components to camera components; kappa turns about the object vertical, phi about the
    camera's cross-track axis (a backward-looking camera has phi < 0), omega about its
    along-track axis. Valid for |phi| < 90 deg.
    """
    phi = float(np.arcsin(np.clip(m[0, 2], -1.0, 1.0)))
    omega = float(np.arctan2(-m[1, 2], m[2, 2]))
    kappa = float(np.arctan2(-m[0, 1], m[0, 0]))
    return omega, phi, kappa
