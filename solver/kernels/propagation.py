"""Orbit propagation in the Earth-fixed frame with its variational equations (numba).

Used by the pass-propagated platform models (:mod:`solver.platforms.orbit_pass`, docs/models.md
section 12): one state x0 = (position, velocity) in ECEF at the pass reference epoch is
integrated to the epoch of every image line.

Force model (ECEF, rotating with the Earth at Omega about z; units m, s)::

    r'' = g(r) + Omega^2 (x, y, 0) + 2 Omega (v_y, -v_x, 0)

with g the point-mass gravity plus J2 (J2 = 0 gives the two-body model), the centrifugal and the
Coriolis terms. Variational equations: Phi' = F Phi with F = [[0, I], [G, W]], G = dg/dr +
diag(Omega^2, Omega^2, 0), W = [[0, 2 Omega, 0], [-2 Omega, 0, 0], [0, 0, 0]], Phi(0) = I.

Integrator: classical fixed-step Runge-Kutta 4 applied to the augmented system (state and
Phi): Phi is then the *exact* derivative of the discrete RK4 map (the chain rule through every
stage), so the Jacobians the adjustment uses are exact for the trajectory it evaluates. Step
1 s: the truncation is ~1e-8 m over 100 s (tests/solver/platforms/test_orbit_pass.py checks the state against an
independent DOP853 integration in the inertial frame).

Between nodes (every ``NODE_STEP_S``) the state is a quintic Hermite polynomial through the
positions, velocities and accelerations of the two neighbouring nodes; its derivatives wrt x0
are the same polynomial through the node derivatives (dS, dV, dA = G dS + W dV), so the
interpolated position, its time derivatives and its x0-derivatives are mutually consistent.

Segment layout inside an image's constant vector ``kc`` (after the 18 Kepler constants; see
:mod:`solver.kernels`): ``PASS_T_OFF`` line-0 epoch minus pass reference epoch (s), pass index,
node count, time of node 0 (s, relative to the reference epoch), node step (s), the x0 the
segment was computed for (6), the attitude time offset (0: attitude polynomials in time since
the image's first line; ``PASS_T_OFF``: since the pass reference epoch, for attitude shared by
the images of one camera), then ``NODE_SIZE`` values per node: S, V, A (ECEF) and dS/dx0,
dV/dx0, dA/dx0 (3 x 6 each, row-major).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.kernels.layout import JIT as _JIT
from solver.kernels.layout import LEAF as _LEAF
from solver.kernels.layout import (  # noqa: F401  (the segment layout, defined with the other offsets; re-exported)
    NODE_SIZE,
    NODE_STEP_S,
    PASS_ATT_OFF,
    PASS_INDEX,
    PASS_NODE0,
    PASS_NODES,
    PASS_STEP,
    PASS_T0,
    PASS_T_OFF,
    PASS_X0,
    segment_length,
)

# kc layout (indices into an image's constant vector)
KC_GM, KC_OMEGA, KC_J2, KC_AE = 12, 13, 14, 15
RK_STEP_S = 1.0
# coefficient slots (solver.kernels: element * 4 + power) that carry d/dx0 in the kernels' outputs
PASS_COEF_INDEX = np.array([0, 4, 8, 1, 5, 9], dtype=np.int64)


@njit(**_JIT)
def gravity_and_gradient(r, gm: float, j2: float, ae: float):
    """Acceleration (m/s^2) of point mass + J2 at ECEF position r (m) and its 3x3 gradient."""
    g = np.empty(3)
    grad = np.empty((3, 3))
    gravity_and_gradient_into(r[0], r[1], r[2], gm, j2, ae, g, grad)
    return g, grad


@njit(**_LEAF)
def gravity_and_gradient_into(x: float, y: float, z: float, gm: float, j2: float, ae: float, g, grad) -> None:
    """:func:`gravity_and_gradient` at the ECEF position (x, y, z) (m) into ``g`` (3) and
    ``grad`` (3 x 3)."""
    r2 = x * x + y * y + z * z
    rn = np.sqrt(r2)
    r3 = r2 * rn
    r5 = r3 * r2
    for i in range(3):
        ri = x if i == 0 else (y if i == 1 else z)
        g[i] = -gm * ri / r3
        for j in range(3):
            rj = x if j == 0 else (y if j == 1 else z)
            grad[i, j] = -gm * ((1.0 if i == j else 0.0) / r3 - 3.0 * ri * rj / r5)
    if j2 != 0.0:
        k = 1.5 * j2 * gm * ae * ae
        r7 = r5 * r2
        r9 = r7 * r2
        z2 = z * z
        # g_i = -k * r_i * (c_i r^-5 - 5 z^2 r^-7), c = (1, 1, 3)
        for i in range(3):
            ri = x if i == 0 else (y if i == 1 else z)
            ci = 3.0 if i == 2 else 1.0
            g[i] += -k * ri * (ci / r5 - 5.0 * z2 / r7)
            for j in range(3):
                rj = x if j == 0 else (y if j == 1 else z)
                dz2 = 2.0 * z if j == 2 else 0.0
                dbr = -5.0 * ci * rj / r7 - 5.0 * (dz2 / r7 - 7.0 * z2 * rj / r9)
                br = ci / r5 - 5.0 * z2 / r7
                grad[i, j] += -k * ((1.0 if i == j else 0.0) * br + ri * dbr)


@njit(**_JIT)
def rotating_acceleration(r, v, gm: float, omega: float, j2: float, ae: float):
    """Acceleration in the rotating frame and its derivatives G = da/dr, W = da/dv."""
    g, gg = gravity_and_gradient(r, gm, j2, ae)
    a = g.copy()
    a[0] += omega * omega * r[0] + 2.0 * omega * v[1]
    a[1] += omega * omega * r[1] - 2.0 * omega * v[0]
    gg[0, 0] += omega * omega
    gg[1, 1] += omega * omega
    w = np.zeros((3, 3))
    w[0, 1] = 2.0 * omega
    w[1, 0] = -2.0 * omega
    return a, gg, w


@njit(**_JIT)
def _deriv(y, phi, gm, omega, j2, ae, dy, dphi):
    a, gg, w = rotating_acceleration(y[0:3], y[3:6], gm, omega, j2, ae)
    for i in range(3):
        dy[i] = y[3 + i]
        dy[3 + i] = a[i]
    for c in range(6):
        for i in range(3):
            dphi[i, c] = phi[3 + i, c]
            acc = 0.0
            for j in range(3):
                acc += gg[i, j] * phi[j, c] + w[i, j] * phi[3 + j, c]
            dphi[3 + i, c] = acc


@njit(**_JIT)
def rk4_step(y, phi, h: float, gm: float, omega: float, j2: float, ae: float):
    """One RK4 step of the state and its transition matrix (new arrays)."""
    k1 = np.empty(6)
    p1 = np.empty((6, 6))
    k2 = np.empty(6)
    p2 = np.empty((6, 6))
    k3 = np.empty(6)
    p3 = np.empty((6, 6))
    k4 = np.empty(6)
    p4 = np.empty((6, 6))
    _deriv(y, phi, gm, omega, j2, ae, k1, p1)
    _deriv(y + 0.5 * h * k1, phi + 0.5 * h * p1, gm, omega, j2, ae, k2, p2)
    _deriv(y + 0.5 * h * k2, phi + 0.5 * h * p2, gm, omega, j2, ae, k3, p3)
    _deriv(y + h * k3, phi + h * p3, gm, omega, j2, ae, k4, p4)
    return y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4), phi + h / 6.0 * (p1 + 2.0 * p2 + 2.0 * p3 + p4)


@njit(**_JIT)
def propagate(y, phi, dt: float, gm: float, omega: float, j2: float, ae: float):
    """Integrate (state, Phi) over dt seconds (either sign) in equal steps of at most RK_STEP_S."""
    n = int(math.ceil(abs(dt) / RK_STEP_S - 1e-9))
    if n == 0:
        return y.copy(), phi.copy()
    h = dt / n
    for _ in range(n):
        y, phi = rk4_step(y, phi, h, gm, omega, j2, ae)
    return y, phi


@njit(**_JIT)
def _write_node(kc, k, y, phi, gm, omega, j2, ae):
    a, gg, w = rotating_acceleration(y[0:3], y[3:6], gm, omega, j2, ae)
    b = PASS_NODE0 + k * NODE_SIZE
    for i in range(3):
        kc[b + i] = y[i]
        kc[b + 3 + i] = y[3 + i]
        kc[b + 6 + i] = a[i]
        for c in range(6):
            da = 0.0
            for j in range(3):
                da += gg[i, j] * phi[j, c] + w[i, j] * phi[3 + j, c]
            kc[b + 9 + i * 6 + c] = phi[i, c]
            kc[b + 27 + i * 6 + c] = phi[3 + i, c]
            kc[b + 45 + i * 6 + c] = da


@njit(**_JIT)
def build_segment(kc, x0) -> None:
    """(Re)compute the node table in ``kc`` (in place) for the pass state ``x0`` (ECEF m, m/s)."""
    gm, omega, j2, ae = kc[KC_GM], kc[KC_OMEGA], kc[KC_J2], kc[KC_AE]
    n = int(kc[PASS_NODES])
    h = kc[PASS_STEP]
    y = np.empty(6)
    for i in range(6):
        y[i] = x0[i]
        kc[PASS_X0 + i] = x0[i]
    phi = np.eye(6)
    y, phi = propagate(y, phi, kc[PASS_T0], gm, omega, j2, ae)
    for k in range(n):  # (node 0 inside the loop: a constant index would compile _write_node twice)
        if k > 0:
            y, phi = propagate(y, phi, h, gm, omega, j2, ae)
        _write_node(kc, k, y, phi, gm, omega, j2, ae)


@njit(**_JIT)
def ensure_segment(kc, x0) -> None:
    """Recompute the segment only if it was computed for another x0."""
    for i in range(6):
        if kc[PASS_X0 + i] != x0[i]:
            build_segment(kc, x0)
            return


@njit(**_LEAF)
def _hermite_basis(kc, t: float, b) -> int:
    """Fill ``b`` (3 x 6) with the quintic Hermite basis at ``t`` (values, first and second time
    derivatives, over the two nodes' position, velocity and acceleration) and return the index
    of the interval's first node. Outside the node range the end interval is extended."""
    n = int(kc[PASS_NODES])
    h = kc[PASS_STEP]
    u = (t - kc[PASS_T0]) / h
    k = int(math.floor(u))
    if k < 0:
        k = 0
    if k > n - 2:
        k = n - 2
    s = u - k
    s2 = s * s
    s3 = s2 * s
    s4 = s3 * s
    s5 = s4 * s
    # quintic Hermite basis (values, first and second derivatives in s)
    b[0, 0] = 1.0 - 10.0 * s3 + 15.0 * s4 - 6.0 * s5
    b[0, 1] = (s - 6.0 * s3 + 8.0 * s4 - 3.0 * s5) * h
    b[0, 2] = (0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5) * h * h
    b[0, 3] = 10.0 * s3 - 15.0 * s4 + 6.0 * s5
    b[0, 4] = (-4.0 * s3 + 7.0 * s4 - 3.0 * s5) * h
    b[0, 5] = (0.5 * s3 - s4 + 0.5 * s5) * h * h
    b[1, 0] = (-30.0 * s2 + 60.0 * s3 - 30.0 * s4) / h
    b[1, 1] = 1.0 - 18.0 * s2 + 32.0 * s3 - 15.0 * s4
    b[1, 2] = (s - 4.5 * s2 + 6.0 * s3 - 2.5 * s4) * h
    b[1, 3] = (30.0 * s2 - 60.0 * s3 + 30.0 * s4) / h
    b[1, 4] = -12.0 * s2 + 28.0 * s3 - 15.0 * s4
    b[1, 5] = (1.5 * s2 - 4.0 * s3 + 2.5 * s4) * h
    b[2, 0] = (-60.0 * s + 180.0 * s2 - 120.0 * s3) / (h * h)
    b[2, 1] = (-36.0 * s + 96.0 * s2 - 60.0 * s3) / h
    b[2, 2] = 1.0 - 9.0 * s + 18.0 * s2 - 10.0 * s3
    b[2, 3] = (60.0 * s - 180.0 * s2 + 120.0 * s3) / (h * h)
    b[2, 4] = (-24.0 * s + 84.0 * s2 - 60.0 * s3) / h
    b[2, 5] = 3.0 * s - 12.0 * s2 + 10.0 * s3
    return k


@njit(**_LEAF)
def pass_values_into(kc, t: float, b, pos, vel, acc) -> int:
    """ECEF position, velocity and acceleration at ``t`` into ``pos``, ``vel``, ``acc`` (no
    allocation: the Newton iterations of the projection call this); ``b`` (3 x 6) is scratch
    left holding the basis. Returns the interval's first node index."""
    k = _hermite_basis(kc, t, b)
    b0 = PASS_NODE0 + k * NODE_SIZE
    b1 = b0 + NODE_SIZE
    for i in range(3):
        p0, v0, a0 = kc[b0 + i], kc[b0 + 3 + i], kc[b0 + 6 + i]
        p1, v1, a1 = kc[b1 + i], kc[b1 + 3 + i], kc[b1 + 6 + i]
        pos[i] = b[0, 0] * p0 + b[0, 1] * v0 + b[0, 2] * a0 + b[0, 3] * p1 + b[0, 4] * v1 + b[0, 5] * a1
        vel[i] = b[1, 0] * p0 + b[1, 1] * v0 + b[1, 2] * a0 + b[1, 3] * p1 + b[1, 4] * v1 + b[1, 5] * a1
        acc[i] = b[2, 0] * p0 + b[2, 1] * v0 + b[2, 2] * a0 + b[2, 3] * p1 + b[2, 4] * v1 + b[2, 5] * a1
    return k


@njit(**_JIT)
def pass_state(kc, t: float, want_jac: bool):
    """ECEF position, velocity and acceleration at ``t`` (s after the pass reference epoch) from
    the segment in ``kc``, and (want_jac) dS/dx0 and dV/dx0 (3 x 6).

    Outside the node range the end interval's polynomial is extended (Newton iterates only).
    """
    b = np.empty((3, 6))
    pos = np.empty(3)
    vel = np.empty(3)
    acc = np.empty(3)
    k = pass_values_into(kc, t, b, pos, vel, acc)
    ds = np.zeros((3, 6))
    dv = np.zeros((3, 6))
    if want_jac:
        for c in range(6):
            pass_state_column(kc, b, k, c, ds[:, c], dv[:, c])
    return pos, vel, acc, ds, dv


@njit(**_LEAF)
def pass_state_column(kc, b, k: int, c: int, ds, dv) -> None:
    """Column ``c`` of dS/dx0 and dV/dx0 (ECEF) into ``ds``, ``dv`` (3 each): the node
    derivatives of interval ``k`` through the Hermite basis ``b`` of :func:`_hermite_basis`."""
    b0 = PASS_NODE0 + k * NODE_SIZE
    b1 = b0 + NODE_SIZE
    for i in range(3):
        q = i * 6 + c
        p0, v0, a0 = kc[b0 + 9 + q], kc[b0 + 27 + q], kc[b0 + 45 + q]
        p1, v1, a1 = kc[b1 + 9 + q], kc[b1 + 27 + q], kc[b1 + 45 + q]
        ds[i] = b[0, 0] * p0 + b[0, 1] * v0 + b[0, 2] * a0 + b[0, 3] * p1 + b[0, 4] * v1 + b[0, 5] * a1
        dv[i] = b[1, 0] * p0 + b[1, 1] * v0 + b[1, 2] * a0 + b[1, 3] * p1 + b[1, 4] * v1 + b[1, 5] * a1

