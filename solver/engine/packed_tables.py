"""Packed constant tables for the numba residual kernels (:mod:`solver.kernels`).

The per-image and per-camera constants live once in two arrays; every observation is a short
record pointing into them, so a residual block costs one numba dispatch with few arguments.
"""

from __future__ import annotations

import numpy as np

from solver.blocks import registry as blocks
from solver.kernels import (
    CAM_TAB,
    IMG_TAB,
    IT_BASE,
    IT_FREE,
    IT_KIND,
    IT_NFREE,
    KC_START,
    N_IOP,
    OBS_REC,
    REC_CAM_SLOT,
    REC_CAMERA,
    REC_CHIP,
    REC_CHIP_LEN,
    REC_IMAGE,
    REC_IMG_SLOT,
    REC_OC,
    REC_PASS_SLOT,
)
from solver.state import AdjustmentState


def image_table(problem: AdjustmentState) -> np.ndarray:
    """One row per image: kind, nfree, free indices, base coefficients, kc (pass images: with
    their propagated segment, so rows are as long as the longest kc)."""
    width = max([IMG_TAB] + [KC_START + len(im.kc) for im in problem.images])
    tab = np.zeros((len(problem.images), width))
    for im in problem.images:
        r = tab[im.index]
        r[IT_KIND] = im.kind
        r[IT_NFREE] = im.nfree
        r[IT_FREE : IT_FREE + im.nfree] = im.free_idx
        r[IT_BASE:KC_START] = im.base
        r[KC_START : KC_START + len(im.kc)] = im.kc
    return tab


def camera_table(problem: AdjustmentState) -> np.ndarray:
    tab = np.zeros((max(len(problem.cameras), 1), CAM_TAB))
    for c in problem.cameras:
        r = tab[c.index]
        r[0] = c.nfree
        r[1] = 1.0 if c.has_iop else 0.0
        r[2 : 2 + c.nfree] = c.free_idx
        r[2 + N_IOP : 2 + 2 * N_IOP] = c.base
    return tab


def chip_lengths(problem: AdjustmentState) -> np.ndarray:
    """Chip lengths (mm) indexed [camera, chip]; the last row (camera -1: RPC images) is 0."""
    width = max([1] + [len(c.chip_len_mm) for c in problem.cameras])
    out = np.zeros((len(problem.cameras) + 1, width))
    for c in problem.cameras:
        out[c.index, : len(c.chip_len_mm)] = c.chip_len_mm
    return out


def records(
    problem: AdjustmentState,
    rows: np.ndarray,
    img_slot: np.ndarray | None = None,
    cam_slot: np.ndarray | None = None,
    pass_slot: np.ndarray | None = None,
) -> np.ndarray:
    """Observation records of ``rows``; slots default to -1 (filled by the block builders)."""
    obs = problem.obs
    rec = np.zeros((len(rows), OBS_REC))
    rec[:, REC_IMAGE] = obs.img[rows]
    rec[:, REC_CAMERA] = obs.cam[rows]
    rec[:, REC_IMG_SLOT] = -1 if img_slot is None else img_slot
    rec[:, REC_CAM_SLOT] = -1 if cam_slot is None else cam_slot
    rec[:, REC_CHIP] = obs.chip_idx[rows]
    rec[:, REC_CHIP_LEN] = chip_lengths(problem)[obs.cam[rows], obs.chip_idx[rows]]
    rec[:, REC_OC:REC_PASS_SLOT] = obs.oc[rows]
    rec[:, REC_PASS_SLOT] = -1 if pass_slot is None else pass_slot
    return np.ascontiguousarray(rec)


def current_tables(problem: AdjustmentState):
    """(image table, camera table, image free parameters (nimg, 24), camera free parameters);
    the kinds' derived values (pass segments) are brought up to date with their blocks first."""
    blocks.refresh(problem)
    img_tab, cam_tab = image_table(problem), camera_table(problem)
    img_p = np.zeros((len(problem.images), 24))
    for im in problem.images:
        img_p[im.index, : im.nfree] = im.params
    cam_p = np.zeros((max(len(problem.cameras), 1), N_IOP))
    for c in problem.cameras:
        cam_p[c.index, : c.nfree] = c.params
    return img_tab, cam_tab, img_p, cam_p
