"""Numbers the kernels share with the Python side: the platform kinds' dispatch codes, vector
sizes, and the named offsets of the packed image/camera tables and observation records.

No kernel lives here. A platform kind (:mod:`solver.platforms.kinds`) carries its dispatch code
(``kernel``); the kernels branch on it in :mod:`solver.kernels.platform` (platform evaluation)
and :mod:`solver.kernels.projection` (the projection entry point), nowhere else.
"""

from __future__ import annotations

from solver.schema.iop_names import IOP_CHIP, IOP_OPTICAL, MAX_CHIPS

KIND_POLYNOMIAL = 0  # polynomials of tau = L / 1000 in the LGS
KIND_KEPLER = 1  # Earth-fixed state at line 0, Kepler/J2 quadratic, angles in the LGS
KIND_ORBIT_ATTITUDE = 2  # Kepler/J2 position, attitude relative to the orbital frame
KIND_PASS = 3  # one propagated orbit per pass (solver.kernels.propagation), attitude as orbit-attitude
KIND_RPC = 4  # RPC00B plus an image-space bias (solver.kernels.rpc): no camera, no platform
N_COEF = 24
N_OBS_CONST = 9
N_KEPLER_CONST = 18
# kc slot of the attitude base's address in kc (0: none; solver.blocks.platform.attach_attitude_base
# appends the table after everything else, solver.kernels.platform._attitude_base_into reads it):
# n, then n times (the angle polynomials' time, s), then n roll, n pitch, n yaw (rad)
KC_ATT_BASE = 17
# full IOP vector of a camera: x0, y0, df, k1, k2, sy, then per chip (a0, b0, a1, b1, delta)
N_IOP = len(IOP_OPTICAL) + len(IOP_CHIP) * MAX_CHIPS

JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)  # options of every @njit here
# options of the leaf kernels: those that allocate nothing, get no array from a call and return
# no array (they fill arrays they are given, or return floats). Without numba's reference counts
# (``_nrt=False``) a call no longer increments and decrements the count of every array argument
# atomically: measured 150 ns for a call with ten arrays, more than the arithmetic of a Newton
# step on the line. numba refuses to compile an allocation in such a kernel; returning an array
# from one (a count the caller would release and nobody took) is what this rule forbids.
LEAF = dict(JIT, _nrt=False)

# ---- residual blocks over image and camera tables ----------------------------------------
# img_tab row (68): kind, nfree, free_idx[24], base[24], kc[18]
# cam_tab row (2 + 2 N_IOP): nfree, has_iop, free_idx[N_IOP], base[N_IOP]
# (the pass kind appends its propagated segment to kc: the row is then longer, see
#  solver.kernels.propagation; kc is always it[KC_START:])
# observation record (16): image, camera, image slot, camera slot (-1: constant), chip index,
#                          chip length (mm), oc[9], pass slot (-1: constant or no pass)
# named offsets of the packed rows (solver.engine.packed_tables writes them, the kernels read them)
IT_KIND = 0  # img_tab: model kind (KIND_*)
IT_NFREE = 1  # img_tab: number of free coefficients
IT_FREE = 2  # img_tab: free coefficient indices, N_COEF slots
IT_BASE = IT_FREE + N_COEF  # img_tab: full coefficient vector (held and current), N_COEF long
KC_START = IT_BASE + N_COEF  # img_tab: kc, N_KEPLER_CONST long (pass kind: + its segment)
IMG_TAB = KC_START + N_KEPLER_CONST
CAM_TAB = 2 + 2 * N_IOP
REC_IMAGE = 0  # observation record: image index
REC_CAMERA = 1  # camera index
REC_IMG_SLOT = 2  # image parameter slot (-1: constant)
REC_CAM_SLOT = 3  # camera parameter slot (-1: constant)
REC_CHIP = 4  # chip index in the camera
REC_CHIP_LEN = 5  # chip length (mm)
REC_OC = 6  # oc[N_OBS_CONST]: line, column, sigma_px, ...
REC_LINE = REC_OC  # observed line (px)
REC_COLUMN = REC_OC + 1  # observed column (px)
REC_SIGMA = REC_OC + 2  # sigma (px)
REC_PASS_SLOT = REC_OC + N_OBS_CONST  # pass parameter slot (-1: constant or no pass)
OBS_REC = REC_PASS_SLOT + 1

# ---- image-line forms of the straight-line kernels (solver.kernels.lines) ------------------
FORM_Y = 0  # y = a x + b
FORM_X = 1  # x = a' y + b'

# the pseudo-frame map of fitted image lines given in pixels (x = line, y = column)
PIXEL_MAP = (0.0, 0.0, 1.0, 0.0, 0.0, 1.0)

# ---- descriptor of a straight-line term (solver.observations.lines.LineTerm; int64 words) ---
LT_PLANES, LT_DISTANCES, LT_FITTED = 0, 1, 2  # the term's model (LT_MODE)
LT_MODE = 0
LT_KIND = 1  # the image's platform kind
LT_NFREE = 2  # the image's free coefficients (the parameter block's size)
LT_M = 3  # residual rows
LT_KC = 4  # address of the image's constants kc
LT_KC_LEN = 5
LT_BASE = 6  # address of the image's full coefficient vector (24 doubles)
LT_FREE = 7  # address of the free coefficients' indices (LT_NFREE int64)
LT_P1 = 8  # addresses of the object line's endpoints (3 doubles each, LGS m)
LT_P2 = 9
LT_W = 10  # address of the whitening matrix (LT_M x LT_M, row-major)
LT_TARGET = 11  # address of the observed (a, b) less the correction (planes) or the fitted (a, b)
LT_OCS = 12  # address of the points' constants (LT_M x 9; fitted: the endpoints' 2 x 9)
LT_S = 13  # address of the closest points' parameters (LT_M doubles; updated in place)
LT_SCAL = 14  # address of (tau, focal length mm, form) of the planes model and the fitted form
LT_WORDS = 15

# ---- pass segment inside an image's kc (solver.kernels.propagation writes and reads it) ----
PASS_T_OFF = N_KEPLER_CONST  # line-0 epoch minus the pass reference epoch (s)
PASS_INDEX = PASS_T_OFF + 1
PASS_NODES = PASS_T_OFF + 2
PASS_T0 = PASS_T_OFF + 3
PASS_STEP = PASS_T_OFF + 4
PASS_X0 = PASS_T_OFF + 5  # 6 values
PASS_ATT_OFF = PASS_T_OFF + 11  # added to t (s since the image's first line) for the attitude polynomials
PASS_NODE0 = PASS_T_OFF + 12
NODE_SIZE = 63
NODE_STEP_S = 1.0


def segment_length(n_nodes: int) -> int:
    """Length of the pass part of ``kc`` (header and nodes) for ``n_nodes`` nodes."""
    return PASS_NODE0 - PASS_T_OFF + n_nodes * NODE_SIZE
