"""Numerical kernels (numba): rotation, platform evaluation and the pushbroom projection.

The package is split by concern; this file holds the conventions and re-exports the public
names (``from solver.kernels import project`` keeps working):

* :mod:`solver.kernels.layout`: kinds' dispatch codes, sizes, packed-table offsets (no kernel);
* :mod:`solver.kernels.rotation`: rotations and frames (M(omega, phi, kappa), mounting, orbital frame);
* :mod:`solver.kernels.platform`: platform evaluation (position and rotation at tau, per kind);
* :mod:`solver.kernels.projection`: the projection, its inverse (rays) and ray intersection,
  with :func:`project_observation` the one entry point of the observation blocks;
* :mod:`solver.kernels.blocks`: the observation blocks over the packed tables;
* :mod:`solver.kernels.propagation`, :mod:`solver.kernels.rpc`: orbit propagation and pass
  states; the RPC00B ground-to-image of the RPC kind.

Everything that runs once per observation per solver evaluation lives here, compiled with numba
(``error_model="numpy"`` so a division by zero gives inf instead of raising inside Ceres).
The residual blocks in :mod:`solver.engine.backend` and the covariance code (:mod:`solver.engine.linalg`) call only
these functions, so a compiled C++ kernel could replace this package behind the same interface.
:mod:`solver.kernels.cache` is the disk cache of the compiled kernels, keyed on their sources
(every module with ``@njit`` imports it first).

Importing the package loads no kernel and not numba: the layout's numbers are plain attributes,
and a kernel's name imports its module on first use (PEP 562). Validation, the job schema and
the server's API process use only the numbers, so they never load numba (about 125 MB of a
process's memory; tests/solver/kernels/test_lazy_kernels.py pins it).

Conventions (see docs/models.md):

* Rotation object -> camera: ``M(omega, phi, kappa) = Rx(omega) Ry(phi) Rz(kappa)`` with
  right-handed active elementary matrices. kappa turns about the object vertical (heading),
  phi about the camera's cross-track axis (pitch: a backward-looking camera has phi < 0),
  omega about the camera's along-track axis (roll).
* Camera frame: x_c along track (flight direction), z_c away from the scene, y_c = z_c x x_c.
  ``d = M (P - S)``; the image coordinates are ``x = -f d_x / d_z``, ``y = -f d_y / d_z`` (mm).
* Platform parameters of one image are a *full* coefficient vector ``coef[6, 4]`` (flattened to
  24) for the elements (X, Y, Z, omega, phi, kappa) and powers tau^0..tau^3 of the model's scaled
  time ``tau``. Polynomial models: every element is ``sum_k coef[e, k] tau^k`` in the LGS.
  Kepler models: coef[0:3, 0] is the ECEF position S0 at line 0, coef[0:3, 1] the ECEF velocity
  u, and the position is ``S0 + u tau + 1/2 a tau^2`` with the rotating-frame acceleration
  ``a = g(S0) + Omega^2 (X0, Y0, 0) + 2 Omega (u_y, -u_x, 0)`` (g: point mass, optionally J2);
  the result is rotated into the LGS. Angles are polynomials for every model.
* Kepler constants ``kc`` (18): R_ecef->lgs (9, row-major), LGS origin in ECEF (3), GM, Omega,
  J2 (0 disables), a_e, camera mounting pitch (rad, orbit-attitude models), the address in kc
  of the image's attitude base (0: none; the delivered attitude the angle polynomials correct,
  :func:`solver.kernels.platform._attitude_base_into`).
* Observation constants ``oc`` (9): line, column, sigma_px, f_mm, pixel_mm, xo_mm, yo_mm,
  c_centre, tau_per_line, where the projection condition is ``-f d_x/d_z = xo`` (xo = chip dx -
  principal point x0) and ``column = c_centre + (-f d_y/d_z - yo) / pixel`` (yo = chip dy - y0).
"""

from __future__ import annotations

import importlib
from typing import Any

from solver.kernels.layout import (
    CAM_TAB,
    IMG_TAB,
    IT_BASE,
    IT_FREE,
    IT_KIND,
    IT_NFREE,
    KC_ATT_BASE,
    KC_START,
    KIND_KEPLER,
    KIND_ORBIT_ATTITUDE,
    KIND_PASS,
    KIND_POLYNOMIAL,
    KIND_RPC,
    N_COEF,
    N_IOP,
    N_KEPLER_CONST,
    N_OBS_CONST,
    OBS_REC,
    PASS_ATT_OFF,
    PASS_INDEX,
    PASS_T_OFF,
    REC_CAM_SLOT,
    REC_CAMERA,
    REC_CHIP,
    REC_CHIP_LEN,
    REC_COLUMN,
    REC_IMAGE,
    REC_IMG_SLOT,
    REC_LINE,
    REC_OC,
    REC_PASS_SLOT,
    REC_SIGMA,
)
from solver.schema.iop_names import IOP_CHIP, IOP_OPTICAL, MAX_CHIPS

# the compiled kernels' names and the module of each, imported on first use
_KERNEL_MODULES = {
    "blocks": ("_eval_record", "_fill", "_put_rows", "all_observation_blocks", "fixed_obs_block", "observation_blocks_into", "point_obs_block"),
    "platform": (
        "_attitude_angles", "_attitude_base_into", "_attitude_time", "_camera_state", "_coef_gradients_into", "_kepler_terms", "_derivative_factors",
        "_oa_factors_into", "_oa_frames_into", "_oa_pose", "_oa_state_gradients", "_projection_terms", "_projection_work", "_pose", "_state_column", "assemble", "object_to_camera", "platform_state",
    ),
    "projection": (
        "_line_newton_step", "camera_model", "ideal_direction", "intersect_all", "project", "project_cam",
        "project_observation", "ray", "ray_cam",
    ),
    "propagation": ("PASS_COEF_INDEX", "ensure_segment", "gravity_and_gradient", "pass_state", "pass_state_column"),
    "rotation": ("_mount", "_orbital_frame", "_orbital_frame_rate", "_rotation_into", "ro_offset_scalars", "rotation_and_derivatives"),
    "rpc": ("rpc_project", "rpc_ray"),
}
_HOME = {name: module for module, names in _KERNEL_MODULES.items() for name in names}


def __getattr__(name: str) -> Any:
    """A kernel's name: import its module (and numba) now, keep the name here for next time."""
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module 'solver.kernels' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"solver.kernels.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOME))


__all__ = [
    "CAM_TAB", "IMG_TAB", "IOP_CHIP", "IOP_OPTICAL", "IT_BASE", "IT_FREE", "IT_KIND", "IT_NFREE",
    "KC_ATT_BASE", "KC_START", "KIND_KEPLER", "KIND_ORBIT_ATTITUDE", "KIND_PASS", "KIND_POLYNOMIAL", "KIND_RPC",
    "MAX_CHIPS", "N_COEF", "N_IOP", "N_KEPLER_CONST", "N_OBS_CONST", "OBS_REC", "PASS_ATT_OFF",
    "PASS_COEF_INDEX", "PASS_INDEX", "PASS_T_OFF", "REC_CAMERA", "REC_CAM_SLOT", "REC_CHIP",
    "REC_CHIP_LEN", "REC_COLUMN", "REC_IMAGE", "REC_IMG_SLOT", "REC_LINE", "REC_OC",
    "REC_PASS_SLOT", "REC_SIGMA", "_attitude_angles", "_attitude_base_into", "_attitude_time", "_camera_state",
    "_coef_gradients_into", "_eval_record", "_fill", "_kepler_terms", "_derivative_factors", "_oa_factors_into",
    "_oa_frames_into", "_projection_terms", "_projection_work",
    "_line_newton_step", "_mount", "_oa_pose", "_oa_state_gradients", "_orbital_frame",
    "_orbital_frame_rate", "_pose", "_put_rows", "_rotation_into", "_state_column",
    "all_observation_blocks", "assemble", "camera_model", "ensure_segment", "fixed_obs_block",
    "gravity_and_gradient", "ideal_direction", "intersect_all", "object_to_camera", "observation_blocks_into", "pass_state",
    "platform_state", "point_obs_block", "project", "project_cam", "project_observation", "ray",
    "ray_cam", "ro_offset_scalars", "rotation_and_derivatives", "rpc_project", "rpc_ray",
]
