"""The 3-D check of tie points (:mod:`solver.matching.verify`) against a slow reference kept here:
every track intersected on its own (its rays computed afresh, one 3 x 3 system per residual),
the bias estimated with those residuals, the blunder test run track by track, and a
measurement's effect on the other residuals taken by finite differences of the full residuals
(the measurement moved, the whole track computed again). The module computes the same things
for all tracks at once, keeps each image's rays until its bias changes and, for an effect,
computes only the moved image's rays again: these tests fail when that shortcut is wrong (a
stale ray, the wrong rows, an effect summed over the wrong axis or image).

The scene: five views of a local Cartesian frame with a term of the line quadratic in the
column (so a ray's position and direction are not linear in the pixel), tracks of two to five
images whose dicts are not in image order, matching noise, a few blunders, and guiding views
off by a shift of a few pixels.
"""

from __future__ import annotations

import numpy as np
import pytest

from solver.matching import verify as v

HEIGHTS = (0.0, 500.0)
SIZES = [(1000, 1000)] * 5

# The same residual from the same rays, intersected with the sums taken in another order: ~1e-12
# px. A stale ray (a bias not applied), a ray left in that should be out, or the wrong image's
# projection is 1e-3 px or more.
SAME_RESIDUAL_PX = 1e-9
# An effect by the same finite difference (DELTA_PX) computed twice: the 1e-12 px residuals' own
# rounding over 0.05 px, squared; relative 1e-6 leaves room. A missing axis or another image's
# sigma changes a coefficient by 10 % or more.
SAME_EFFECT_REL = 1e-6


class CurvedView:
    """line = (y + tilt z) / gsd + CURVE (x / 1000 m)^2, column = x / gsd, plus the guiding
    orientation's error ``shift`` (pixels)."""

    CURVE = 3.0

    def __init__(self, tilt: float, shift=(0.0, 0.0), gsd: float = 2.0):
        self.tilt, self.shift, self.gsd = tilt, np.asarray(shift, float), gsd

    def ground_to_image(self, xyz):
        xyz = np.atleast_2d(xyz)
        line = (xyz[:, 1] + self.tilt * xyz[:, 2]) / self.gsd + self.CURVE * (xyz[:, 0] / 1000.0) ** 2
        return line + self.shift[0], xyz[:, 0] / self.gsd + self.shift[1], None

    def image_to_ground(self, line, column, height_m=None):
        line, column = np.atleast_1d(line) - self.shift[0], np.atleast_1d(column) - self.shift[1]
        x = column * self.gsd
        h = np.full(len(line), float(height_m))
        return np.column_stack([x, (line - self.CURVE * (x / 1000.0) ** 2) * self.gsd - self.tilt * h, h])


def _scene(seed: int = 3, n_points: int = 150):
    rng = np.random.default_rng(seed)
    tilts = np.linspace(-0.3, 0.3, 5)
    truth = [CurvedView(t) for t in tilts]
    guide = [CurvedView(t, shift=rng.normal(0, 3.0, 2) if i else (0.0, 0.0)) for i, t in enumerate(tilts)]
    pts = np.column_stack([rng.uniform(0, 2000, n_points), rng.uniform(0, 2000, n_points), rng.uniform(0, 500, n_points)])
    tracks, sigmas = [], []
    for p in pts:
        members = [int(i) for i in rng.permutation(rng.choice(5, size=rng.integers(2, 6), replace=False))]
        t = {}
        for i in members:
            line, col, _ = truth[i].ground_to_image(p[None, :])
            t[i] = np.array([line[0], col[0]]) + (rng.normal(0, 0.05 + 0.03 * i, 2) if i != min(members) else 0.0)
        tracks.append(t)
        sigmas.append({i: 0.02 if i == min(t) else 0.05 + 0.02 * i for i in t})
    for k in rng.choice(n_points, 12, replace=False):
        i = max(tracks[k])
        tracks[k][i] = tracks[k][i] + np.array([2.5, 0.0])  # along the epipolar line: a height
    return tracks, sigmas, guide


# --- the slow reference --------------------------------------------------------------------

def _ref_track_residuals(t: dict, models, bias, leave_out: bool) -> dict:
    """One track: each member's ray afresh, each residual's point from its own 3 x 3 system."""
    span = (HEIGHTS[0] - 100.0, HEIGHTS[1] + 100.0)
    rays = {}
    for i, p in t.items():
        q = p - v.apply_bias(bias, i, p[None, :], SIZES[i])[0]
        lo, hi = (models[i].image_to_ground(q[:1], q[1:], height_m=h)[0] for h in span)
        rays[i] = (lo, (hi - lo) / np.linalg.norm(hi - lo))
    if leave_out and len(t) < 3:
        return {}
    out = {}
    for i, p in t.items():
        others = [j for j in t if j != i] if leave_out else list(t)
        a = sum(np.eye(3) - np.outer(rays[j][1], rays[j][1]) for j in others)
        b = sum((np.eye(3) - np.outer(rays[j][1], rays[j][1])) @ rays[j][0] for j in others)
        line, col, _ = models[i].ground_to_image(np.linalg.solve(a, b)[None, :])
        out[i] = p - v.apply_bias(bias, i, p[None, :], SIZES[i])[0] - np.array([line[0], col[0]])
    return out


def _ref_image_bias(tracks, models) -> np.ndarray:
    bias = np.zeros((len(models), 3, 2))
    multi = [t for t in tracks if len(t) >= 3]
    for _ in range(v.BIAS_ITERATIONS):
        largest = 0.0
        for i in range(1, len(models)):
            mine = [t for t in multi if i in t]
            pos = np.array([t[i] for t in mine])
            res = np.array([_ref_track_residuals(t, models, bias, True)[i] for t in mine])
            step = v._robust_affine(v._design(pos, SIZES[i]), res)
            bias[i] += step
            largest = max(largest, float(np.max(np.abs(v._design(pos, SIZES[i]) @ step))))
        if largest < 0.01:
            break
    return bias


def _ref_removed(tracks, sigmas, models, bias) -> list[set[int]]:
    removed = []
    for t0, s in zip(tracks, sigmas, strict=True):
        t, gone = dict(t0), set()
        while len(t) >= 3:
            r = _ref_track_residuals(t, models, bias, True)
            limit = max(v.OUTLIER_SIGMAS * np.sqrt(sum(s[i] ** 2 for i in t)), v.OUTLIER_FLOOR_PX)
            ratio = {i: np.hypot(*r[i]) / limit for i in t}
            worst = max(t, key=lambda i: ratio[i])
            if ratio[worst] <= 1.0:
                break
            drop = [i for i in t if i != min(t)] if (len(t) == 3 or worst == min(t)) else [worst]
            for i in drop:
                gone.add(i)
                del t[i]
        removed.append(gone)
    return removed


def _ref_design(tracks, sigmas, models, bias) -> tuple[np.ndarray, np.ndarray]:
    """Rows (track by track, its images ascending, line then column) of the calibration: each
    effect by moving the measurement and computing the whole track's residuals again."""
    rows, ys = [], []
    for t, s in zip(tracks, sigmas, strict=True):
        r0 = _ref_track_residuals(t, models, bias, True)
        effect = {}
        for j in t:
            if j == min(t):
                continue
            for axis in range(2):
                moved = {**t, j: t[j] + v.DELTA_PX * np.eye(2)[axis]}
                r1 = _ref_track_residuals(moved, models, bias, True)
                for i in t:
                    if i != j:
                        effect.setdefault((i, j), np.zeros((2, 2)))[:, axis] = (r1[i] - r0[i]) / v.DELTA_PX
        for i in sorted(t):
            for axis in range(2):
                a = np.zeros(len(models))
                if i != min(t):
                    a[i] += s[i] ** 2
                for j in t:
                    if (i, j) in effect:
                        a[j] += s[j] ** 2 * np.sum(effect[(i, j)][axis] ** 2)
                rows.append(a)
                ys.append(r0[i][axis] ** 2)
    return np.array(rows), np.array(ys)


# --- the module against it ----------------------------------------------------------------

@pytest.mark.parametrize("leave_out", [False, True])
def test_residuals_of_all_tracks_at_once_are_each_tracks_own(leave_out):
    tracks, _sigmas, guide = _scene()
    bias = np.zeros((5, 3, 2))
    bias[2] = [[0.4, -0.3], [0.2, 0.1], [-0.1, 0.3]]  # affine: the bias depends on the position
    got = v.residuals(tracks, guide, HEIGHTS, bias, SIZES, leave_out=leave_out)
    for t, r in zip(tracks, got, strict=True):
        want = _ref_track_residuals(t, guide, bias, leave_out)
        assert set(r) == set(want)
        for i in want:
            np.testing.assert_allclose(r[i], want[i], rtol=0, atol=SAME_RESIDUAL_PX)


def test_bias_removals_and_residuals_are_the_track_by_track_computation():
    """The bias with each image's rays kept between its bias's steps is the one with every ray
    computed afresh; the blunders removed are those of the test run track by track."""
    tracks, sigmas, guide = _scene()
    removed, bias, final = v.verify(tracks, sigmas, guide, HEIGHTS, SIZES)
    want_bias = _ref_image_bias(tracks, guide)
    np.testing.assert_allclose(bias, want_bias, rtol=0, atol=SAME_RESIDUAL_PX)
    assert np.max(np.abs(bias[1:, 0])) > 1.0  # the guide's shifts are found (not a vacuous comparison)
    want_removed = _ref_removed(tracks, sigmas, guide, want_bias)
    assert removed == want_removed
    assert 12 <= sum(1 for r in removed if r) < 40  # the blunders and a few more, not every track
    for t, g, r in zip(tracks, removed, final, strict=True):
        kept = {i: p for i, p in t.items() if i not in g}
        want = _ref_track_residuals(kept, guide, bias, True) if len(kept) >= 3 else {}
        assert set(r) == set(want)
        for i in want:
            np.testing.assert_allclose(r[i], want[i], rtol=0, atol=SAME_RESIDUAL_PX)


def test_calibration_effects_are_finite_differences_of_the_full_residuals():
    """Each row of sigma_scales' least squares: the effects from the moved image's rays alone
    equal those from the whole track computed again with the measurement moved."""
    tracks, sigmas, guide = _scene()
    removed, bias, _final = v.verify(tracks, sigmas, guide, HEIGHTS, SIZES)
    kept = [{i: p for i, p in t.items() if i not in g} for t, g in zip(tracks, removed, strict=True)]
    multi = [k for k, t in enumerate(kept) if len(t) >= 3]
    ts, ss = [kept[k] for k in multi], [{i: sigmas[k][i] for i in kept[k]} for k in multi]
    block = v._Block(ts, guide, HEIGHTS, SIZES, ss)
    a, y = v._calibration_design(block, bias)
    want_a, want_y = _ref_design(ts, ss, guide, bias)
    assert a.shape == want_a.shape
    np.testing.assert_allclose(y, want_y, rtol=SAME_EFFECT_REL, atol=1e-18)
    np.testing.assert_allclose(a, want_a, rtol=SAME_EFFECT_REL, atol=1e-15)
    assert np.count_nonzero(want_a) > 2 * len(want_y)  # other members' effects are in the rows
