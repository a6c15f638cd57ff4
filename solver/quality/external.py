"""External reliability on points: the effect of every observation's minimal detectable bias on
the adjusted coordinates of every tie point and on the predicted coordinates of every check
point; per point the largest effect and the observation that causes it (docs/quality.md).

From the matrices of :mod:`solver.quality.reliability` (no re-adjustment). A bias ``b``
(whitened) in a group's rows of block ``k`` changes the image/camera/pass parameters by
``dx_f = S^-1 U_k^T b`` (:func:`solver.quality.reliability.bias_effect`); then

* a tie point q of another block moves by ``-C_q^-1 B_q^T dx_f`` (its normal equations
  ``C_q dx_q + B_q^T dx_f = J_q^T b_q`` with no bias in its own rows), the tie point of the
  biased block by ``C_q^-1 (J_q^T b - B_q^T dx_f)``;
* a check point, intersected afterwards from its rays at the adjusted orientation, moves by
  ``-N^-1 J_x^T F dx_f`` (:mod:`solver.quality.precision`: ``N = J_x^T J_x``, ``F`` its rays'
  Jacobian wrt the orientation; a mono point only east, north).

Each component of a group with a finite MDB is one bias (that component alone, sigma0 a
priori); its sign is arbitrary, so effects are reported as magnitudes. Frames: the report's
LGS (east, north, up), metres. Cost: one column of ``S^-1`` products per bias and 3 x (the
point's orientation columns) per point and bias: O(n_bias x (n_orientation^2 + n_points x
block width)); measured in docs/quality.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from solver.quality.precision import ray_blocks
from solver.quality.reliability import Structure, minimal_detectable_bias, redundancy
from solver.state import AdjustmentState

CHUNK = 512  # biases per batch: bounds the memory of the (n_orientation x batch) products


def _biases(st: Structure, lam0_of_dim, dims: list[int]) -> list[tuple[int, int, float]]:
    """(group index, component, whitened bias) for every component with a finite MDB."""
    out = []
    for gi, g in enumerate(st.groups):
        mdb = minimal_detectable_bias(st, g, lam0_of_dim(max(dims[gi], 1)))
        r = redundancy(st, g)
        for k, m in enumerate(mdb):
            if m is not None and r[k] < 1.0:
                out.append((gi, k, m / g.sigma[k]))
    return out


def _label(g) -> dict[str, Any]:
    lab = {k: v for k, v in g.label.items() if k != "role"}
    return {"kind": g.kind, "image": lab.pop("image", None), **lab}


def external_points(
    problem: AdjustmentState, st: Structure, lam0_of_dim, dims: list[int], checkpoints: dict[str, Any] | None
) -> list[dict[str, Any]]:
    """Per tie point and check point: the largest effect of any observation's MDB (3-D and per
    axis of that bias) and which observation; ``dims``: the test dimension of each group (for
    lambda0), ``checkpoints``: the report's check-point section (estimated coordinates)."""
    biases = _biases(st, lam0_of_dim, dims)
    targets = []  # (point id, role, cols, M (3 x cols), own block or -1, own c_inv @ J_p^T)
    for bi, blk in enumerate(st.blocks):
        if blk.jp is None or blk.point < 0 or problem.points[blk.point].role != "tie":
            continue
        targets.append((problem.points[blk.point].id, "tie", blk.cols, -blk.c_inv @ blk.bt, bi, blk.c_inv @ blk.jp.T))
    if checkpoints:
        from solver.engine.linalg import layout

        lay = layout(problem)
        obs = problem.obs
        by_id = {p.id: p for p in problem.points}
        for item in checkpoints.get("points", []):
            p = by_id[item["id"]]
            rows = np.flatnonzero(obs.pt == p.index)
            axes = [0, 1] if item["method"] == "mono" else [0, 1, 2]
            rb = ray_blocks(problem, lay, rows, np.array(item["estimated_lgs_m"]))
            a = rb.jx[:, axes]
            n = a.T @ a
            if not rb.ok or np.linalg.matrix_rank(n) < len(axes):
                continue
            m = np.zeros((3, len(rb.f_cols)))
            m[axes] = -np.linalg.solve(n, a.T @ rb.jf)
            targets.append((p.id, "check", rb.f_cols, m, -1, None))
    if not targets:
        return []
    # targets that touch the same orientation columns (the tie points of one image set) are
    # stacked into one product per batch
    by_cols: dict[tuple[int, ...], list[int]] = {}
    for t, tg in enumerate(targets):
        by_cols.setdefault(tuple(int(c) for c in tg[2]), []).append(t)
    stacks = [
        (
            np.array(key, dtype=np.int64),
            np.array(ts),
            np.vstack([targets[t][3] for t in ts]),
            {targets[t][4]: a for a, t in enumerate(ts) if targets[t][4] >= 0},
        )
        for key, ts in by_cols.items()
    ]
    best = [(0.0, None, None) for _ in targets]  # (3-D effect, enu, bias index)
    best_size = np.zeros(len(targets))
    for c0 in range(0, len(biases), CHUNK):
        chunk = biases[c0 : c0 + CHUNK]
        dx = np.zeros((st.s_inv.shape[0], len(chunk)))
        own: dict[int, list[tuple[int, np.ndarray]]] = {}
        for j, (gi, k, bw) in enumerate(chunk):
            g = st.groups[gi]
            blk = st.blocks[g.block]
            row = g.local[k]
            dx[:, j] = st.s_inv[:, blk.cols] @ (blk.u[row] * bw)
            e = np.zeros(len(blk.rows))
            e[row] = bw
            own.setdefault(g.block, []).append((j, e))
        for cols, ts, m, own_of in stacks:
            own_pos = [(ob, own_of[ob]) for ob in own if ob in own_of]
            eff_all = (m @ dx[cols] if len(cols) else np.zeros((3 * len(ts), len(chunk)))).reshape(len(ts), 3, len(chunk))
            for ob, a in own_pos:  # the biases in a tie point's own rays
                for j, e in own.get(ob, []):
                    eff_all[a, :, j] += targets[ts[a]][5] @ e
            norms = np.sqrt((eff_all**2).sum(axis=1))
            jmax = np.argmax(norms, axis=1)
            vmax = norms[np.arange(len(ts)), jmax]
            for a in np.flatnonzero(vmax > best_size[ts]):
                t = ts[a]
                best_size[t] = vmax[a]
                best[t] = (float(vmax[a]), np.abs(eff_all[a, :, jmax[a]]), c0 + int(jmax[a]))
    out = []
    for (pid, role, *_rest), (size, enu, bi) in zip(targets, best):
        if bi is None:
            out.append({"point": pid, "role": role, "max_effect_m": 0.0, "effect_enu_m": None, "by": None})
            continue
        gi, k, bw = biases[bi]
        g = st.groups[gi]
        out.append(
            {
                "point": pid,
                "role": role,
                "max_effect_m": size,
                "effect_enu_m": {"e": float(enu[0]), "n": float(enu[1]), "u": float(enu[2])},
                "by": {**_label(g), "component": g.components[k], "mdb": float(bw * g.sigma[k]), "units": g.units},
            }
        )
    return out
