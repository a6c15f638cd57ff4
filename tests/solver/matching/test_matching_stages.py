"""Each filtering stage of ``pba match`` on its own: the decision of the stage on inputs built so
that the right answer is known (distances at the ratio threshold, features just inside and
outside the band, a template against noise, two features chained into one track, a sheared
mapping, a blob at a known sub-pixel position). The end-to-end tests (test_matching.py,
test_matching_real.py) check final accuracy on clean scenes, where a loosened stage does not
show; these fail when a stage's threshold or geometry is wrong.
"""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from solver.matching.features import MatchSettings, band_matches
from solver.matching.features import _nearest as _flann
from solver.matching.keypoints import Features, detect
from solver.matching.orientation import MatchImage, PairMapping, rpc_height_range, segment_enters_box
from solver.matching.pipeline import PairMatches
from solver.matching.raster import Raster
from solver.matching.refine import correlate, epipolar_check
from solver.matching.tracks import link

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

SETTINGS = MatchSettings()


class ArrayRaster:
    """An in-memory band with the reads correlation uses (:class:`Raster`'s ``window``)."""

    def __init__(self, values: np.ndarray):
        self.values = values.astype(np.float32)
        self.lines, self.columns = values.shape
        self.stretch = (float(values.min()), float(values.max()))

    def window(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        r0, c0 = max(row0, 0), max(col0, 0)
        return self.values[r0:min(row0 + rows, self.lines), c0:min(col0 + cols, self.columns)]


class AffineModel:
    """A flat-earth stand-in for a sensor model: 'ground' is (line, column, height) of image a;
    image b sees it through ``b = A (line, column) + t + height * parallax``."""

    def __init__(self, a: np.ndarray, t: np.ndarray, parallax: np.ndarray):
        self.a, self.t, self.parallax = a, t, parallax

    def image_to_ground(self, line, column, height_m=None):
        line, column = np.atleast_1d(line), np.atleast_1d(column)
        return np.column_stack([line, column, np.full(len(line), float(height_m))])

    def ground_to_image(self, ground):
        b = ground[:, :2] @ self.a.T + self.t + ground[:, 2:3] * self.parallax
        return b[:, 0], b[:, 1], None


def _image(name: str, raster, model=None) -> MatchImage:
    return MatchImage(name, raster, model)  # type: ignore[arg-type]


# --- ratio test -----------------------------------------------------------------------------

def _one_feature_two_candidates(d1: float, d2: float):
    """One a feature (descriptor 0) whose band holds two b features at descriptor distances d1, d2."""
    da = np.zeros((1, 128), np.float32)
    db = np.zeros((2, 128), np.float32)
    db[0, 0], db[1, 1] = d1, d2
    kb = np.array([[100.0, 100.0], [100.0, 105.0]])
    s0, s1 = np.array([[100.0, 90.0]]), np.array([[100.0, 110.0]])
    return da, db, kb, s0, s1


@pytest.mark.parametrize(("d1", "accepted"), [(70.0, True), (79.9, True), (80.1, False), (90.0, False), (99.0, False)])
def test_ratio_test_at_the_threshold(d1, accepted):
    """Lowe's ratio 0.8: the best candidate (distance d1) is kept only when it is clearly better
    than the second (d2 = 100): 79.9 passes, 80.1 does not, nor anything closer to d2."""
    counts: dict[str, int] = {}
    ia, ib = band_matches(*_one_feature_two_candidates(d1, 100.0), SETTINGS, counts)
    assert counts["candidates"] == 1
    assert len(ia) == int(accepted), (d1, counts)
    assert counts["ratio"] == int(accepted)
    if accepted:
        assert list(ib) == [0]


def _ratio_case_among_many(d1: float, d2: float, distractor: float, n_distractors: int = 1500):
    """The ratio case of a tile searched approximately (FLANN): one a feature
    whose band holds two b features at descriptor distances d1 and d2, among ``n_distractors`` b
    features outside its band at descriptor distance ``distractor``, and 19 other a features
    with nothing in their band."""
    rng = np.random.default_rng(11)
    centre = np.full(128, 100.0, np.float32)
    da = np.vstack([centre, rng.uniform(0, 255, (19, 128))]).astype(np.float32)
    unit = rng.normal(size=(n_distractors, 128))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    e = np.eye(128, dtype=np.float32)
    db = np.vstack([centre + d1 * e[0], centre + d2 * e[1], centre + distractor * unit]).astype(np.float32)
    kb = np.vstack([[100.0, 100.0], [100.0, 105.0], np.column_stack([rng.uniform(400, 900, n_distractors), rng.uniform(0, 900, n_distractors)])])
    s0 = np.vstack([[100.0, 90.0], np.column_stack([np.full(19, 2000.0), np.arange(19) * 40.0])])
    return da, db, kb, s0, s0 + np.array([0.0, 20.0])


@pytest.mark.parametrize(("d2", "distractor"), [(100.0, 300.0), (100.0, 50.0), (400.0, 350.0)])
@pytest.mark.parametrize("below", [True, False])
def test_ratio_test_at_the_threshold_with_the_approximate_search(d2, distractor, below, monkeypatch):
    """The same decision among 1,500 other b features, FLANN searching the tile: the two in the
    band are the nearest of all (300: decided from FLANN's neighbours), behind every other
    (50: none of the nearest is in the band, the band is searched exactly), or the first is
    among the nearest and the second is not (350, with the second at 400: the last neighbour
    bounds the second's distance, too loosely to decide here, so the band is searched exactly).
    d1 just below 0.8 d2 passes, just above does not."""
    from solver.matching import features

    d1 = 0.8 * d2 + (-0.1 if below else 0.1)
    da, db, kb, s0, s1 = _ratio_case_among_many(d1, d2, distractor)
    monkeypatch.setattr(features, "EXACT_PAIRS", 0)  # a tile this small is searched exactly by default
    searched = []
    monkeypatch.setattr(features, "_nearest", lambda *a: searched.append(1) or _flann(*a))
    counts: dict[str, int] = {}
    ia, ib = band_matches(da, db, kb, s0, s1, SETTINGS, counts)
    assert counts["candidates"] == 1
    assert counts["ratio"] == int(below), (d1, d2, distractor, counts)
    assert list(ia) == ([0] if below else []) and list(ib) == ([0] if below else [])
    assert searched  # by FLANN


# --- the epipolar band ----------------------------------------------------------------------

@pytest.mark.parametrize(("offset", "inside"), [
    ((29.0, 0.0), True), ((-29.0, 0.0), True), ((31.0, 0.0), False), ((-31.0, 0.0), False),  # across the segment
    ((0.0, 29.0), True), ((0.0, 31.0), False),  # beyond its far end
    ((0.0, -69.0), True), ((0.0, -71.0), False),  # beyond its near end (the segment is 40 px long)
    ((20.0, 20.0), True), ((22.0, 22.0), False),  # beyond the corner: a distance of 28.3 and 31.1 px
])
def test_band_holds_features_within_search_px_of_the_segment(offset, inside):
    """A b feature is a candidate when it lies within search_px (30) of the a feature's epipolar
    segment: 29 px away it is, 31 px away it is not, across or beyond either end."""
    da = np.zeros((1, 128), np.float32)
    db = np.zeros((1, 128), np.float32)
    s0, s1 = np.array([[500.0, 460.0]]), np.array([[500.0, 500.0]])  # along the columns, 40 px
    kb = s1 + np.array([offset])
    counts: dict[str, int] = {}
    ia, _ib = band_matches(da, db, kb, s0, s1, SETTINGS, counts)
    assert counts["candidates"] == int(inside)
    assert len(ia) == int(inside)


def test_band_on_a_slanted_segment():
    """The band's distance is Euclidean whatever the segment's direction (here 30 degrees)."""
    u = np.array([np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])
    n = np.array([u[1], -u[0]])
    s0 = np.array([[300.0, 300.0]])
    s1 = s0 + 50.0 * u
    da = np.zeros((1, 128), np.float32)
    db = np.zeros((1, 128), np.float32)
    for dist, inside in ((29.5, True), (30.5, False)):
        for side in (1.0, -1.0):
            kb = s0 + 25.0 * u + side * dist * n
            ia, _ = band_matches(da, db, kb, s0, s1, SETTINGS, {})
            assert len(ia) == int(inside), (dist, side)


def test_mutual_check_keeps_one_of_two_a_features_wanting_the_same_b_feature():
    da = np.zeros((2, 128), np.float32)
    da[1, 0] = 3.0
    db = np.zeros((1, 128), np.float32)
    kb = np.array([[100.0, 100.0]])
    s0, s1 = np.array([[100.0, 90.0]] * 2), np.array([[100.0, 110.0]] * 2)
    counts: dict[str, int] = {}
    ia, ib = band_matches(da, db, kb, s0, s1, SETTINGS, counts)
    assert counts["ratio"] == 2 and counts["mutual"] == 1
    assert list(ia) == [0] and list(ib) == [0]


# --- correlation: a template against noise --------------------------------------------------

def _texture(shape, seed: int) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    return 1000.0 + 400.0 * gaussian_filter(rng.normal(size=shape), 1.5)


def test_correlation_finds_a_template_and_refuses_noise():
    """A template cut from a textured image is found again at a sub-pixel shift (NCC near 1,
    position within 0.05 px); the same template against an unrelated texture of the same
    statistics peaks far below min_ncc (0.7) and is refused."""
    from scipy.ndimage import shift as nd_shift

    base = _texture((120, 120), 1)
    half = SETTINGS.template_half_px
    centre = np.array([60, 60])
    tpl = base[centre[0] - half:centre[0] + half + 1, centre[1] - half:centre[1] + half + 1].astype(np.float32)
    moved = nd_shift(base, (2.3, -1.6), order=3, mode="reflect")  # the point is at (62.3, 58.4)
    got = correlate(tpl, _image("b", ArrayRaster(moved)), np.array([61.0, 60.0]), np.eye(2), SETTINGS.min_ncc)
    assert got is not None
    assert got[1] > 0.95
    assert np.allclose(got[0], [62.3, 58.4], atol=0.05), got
    noise = _texture((120, 120), 2)
    assert correlate(tpl, _image("n", ArrayRaster(noise)), np.array([61.0, 60.0]), np.eye(2), SETTINGS.min_ncc) is None
    # the peak on noise is found, just not accepted: with no threshold it would be a match
    found = correlate(tpl, _image("n", ArrayRaster(noise)), np.array([61.0, 60.0]), np.eye(2), -1.0)
    assert found is None or found[1] < SETTINGS.min_ncc


def test_correlation_from_a_far_start_moves_the_whole_search_each_time():
    """A start 10 px off (beyond the +-3 px search) on a smooth texture: the iterations whose peak
    is on the border move by the whole search, so the template is still found (within 0.15 px:
    the smooth texture's peak is broad); a search narrowed to +-1 px after the first iteration
    moves a pixel at a time and gives up (it fails from 8 px)."""
    from scipy.ndimage import gaussian_filter
    from scipy.ndimage import shift as nd_shift

    base = 1000.0 + 400.0 * gaussian_filter(np.random.default_rng(1).normal(size=(160, 160)), 4.0)
    half = SETTINGS.template_half_px
    tpl = base[80 - half:80 + half + 1, 80 - half:80 + half + 1].astype(np.float32)
    moved = nd_shift(base, (2.3, -1.6), order=3, mode="reflect")  # the point is at (82.3, 78.4)
    got = correlate(tpl, _image("b", ArrayRaster(moved)), np.array([72.3, 78.4]), np.eye(2), SETTINGS.min_ncc)
    assert got is not None
    assert np.allclose(got[0], [82.3, 78.4], atol=0.15), got


def _correlate_alone(tpl, other, start, jac, min_ncc):
    """The correlation's iteration (solver.matching.refine's docstring) written plainly, one
    search at a time with OpenCV: the reference the batched searches must reproduce."""
    import cv2

    from solver.matching.refine import CONVERGED_PX, MAX_ITERATIONS, READ_MARGIN_PX, RECENTRED_SEARCH_PX, SEARCH_PX

    def vertex(rm, r0, rp):
        den = rm - 2.0 * r0 + rp
        return 0.0 if den >= 0 else min(max(0.5 * (rm - rp) / den, -0.5), 0.5)

    half = tpl.shape[0] // 2
    p = np.array(start, float)
    on_border = True
    peak = -np.inf
    read, win = (0, 0, 0, 0), None
    for it in range(MAX_ITERATIONS):
        search = SEARCH_PX if on_border else RECENTRED_SEARCH_PX
        u = np.arange(-(half + search), half + search + 1, dtype=float)
        uu, vv = np.meshgrid(u, u, indexing="ij")
        lines, cols = p[0] + jac[0, 0] * uu + jac[0, 1] * vv, p[1] + jac[1, 0] * uu + jac[1, 1] * vv
        r0, c0 = int(np.floor(lines.min())) - 3, int(np.floor(cols.min())) - 3
        r1, c1 = int(np.ceil(lines.max())) + 4, int(np.ceil(cols.max())) + 4
        if r0 < 0 or c0 < 0 or r1 > other.lines or c1 > other.columns:
            return None
        if r0 < read[0] or c0 < read[1] or r1 > read[2] or c1 > read[3]:  # read again, with a margin for the next iterations
            read = (max(r0 - READ_MARGIN_PX, 0), max(c0 - READ_MARGIN_PX, 0), min(r1 + READ_MARGIN_PX, other.lines), min(c1 + READ_MARGIN_PX, other.columns))
            win = other.raster.window(read[0], read[1], read[2] - read[0], read[3] - read[1])
        warped = cv2.remap(win, (cols - read[1]).astype(np.float32), (lines - read[0]).astype(np.float32), cv2.INTER_CUBIC)
        res = cv2.matchTemplate(warped, tpl, cv2.TM_CCOEFF_NORMED).astype(float)
        i, j = np.unravel_index(int(np.argmax(res)), res.shape)
        peak = res[i, j]
        on_border = i in (0, res.shape[0] - 1) or j in (0, res.shape[1] - 1)
        if on_border and it == MAX_ITERATIONS - 1:
            return None
        shift = np.array([i - search, j - search], float)
        if not on_border:
            shift += [vertex(res[i - 1, j], peak, res[i + 1, j]), vertex(res[i, j - 1], peak, res[i, j + 1])]
        p = p + jac @ shift
        if not on_border and np.max(np.abs(shift)) < CONVERGED_PX:
            break
    return (p, peak) if peak >= min_ncc else None


def test_batched_correlation_gives_each_search_its_own_result():
    """Searches run together (correlate_many: in step, whole-array bookkeeping) give what each
    gives alone (the plain loop above): 200 searches in two images and through two affines,
    from starts near (sub-pixel), far (beyond the +-3 px search: the border path), too far
    (still on the border at the last iteration: refused), at the image edge (refused), in an
    unrelated image (noise: refused) and some that do not converge in MAX_ITERATIONS. Positions within 1e-5 px (the batch's parabolas are in float64,
    the plain loop's too: the same numbers up to rounding); the same searches refused."""
    from scipy.ndimage import gaussian_filter
    from scipy.ndimage import shift as nd_shift

    from solver.matching.refine import correlate_many

    rng = np.random.default_rng(11)
    base = _texture((300, 300), 4)
    moved = _image("b", ArrayRaster(nd_shift(base, (2.3, -1.6), order=3, mode="reflect")))
    noise = _image("n", ArrayRaster(_texture((300, 300), 5)))
    smooth = 1000.0 + 400.0 * gaussian_filter(rng.normal(size=(300, 300)), 4.0)  # broad peaks: far starts climb to them
    smooth_moved = _image("s", ArrayRaster(nd_shift(smooth, (2.3, -1.6), order=3, mode="reflect")))
    half = SETTINGS.template_half_px
    tpls, others, starts, jacs = [], [], [], []
    for k in range(200):
        c = rng.integers(half + 30, 300 - half - 30, 2)
        src, other = (smooth, smooth_moved) if k % 5 == 4 else (base, noise if k % 7 == 0 else moved)
        tpls.append(src[c[0] - half:c[0] + half + 1, c[1] - half:c[1] + half + 1].astype(np.float32))
        others.append(other)
        off = rng.uniform(-0.8, 0.8, 2) if k % 3 else rng.uniform(-9.0, 9.0, 2)
        if k % 5 == 4:  # beyond what MAX_ITERATIONS border moves of SEARCH_PX reach: refused
            off = rng.choice([-1.0, 1.0], 2) * rng.uniform(20.0, 24.0, 2)
        if k % 11 == 0:  # the search's window leaves the image: refused
            c[0] = half + 2
        starts.append(c + np.array([2.3, -1.6]) + off)
        jacs.append(np.eye(2) if k % 2 else np.array([[1.0, 0.02], [-0.01, 1.0]]))
    for min_ncc in (SETTINGS.min_ncc, -1.0):  # without a threshold only the iteration refuses
        got = correlate_many(tpls, others, np.array(starts), np.array(jacs), min_ncc)
        alone = [_correlate_alone(*args, min_ncc) for args in zip(tpls, others, starts, jacs, strict=True)]
        assert [g is None for g in got] == [a is None for a in alone]
        found = [(g, a) for g, a in zip(got, alone, strict=True) if a is not None]
        assert 100 < len(found) < 200  # both outcomes are exercised
        for g, a in found:
            assert np.allclose(g[0], a[0], atol=1e-5), (g, a)
            assert abs(g[1] - a[1]) < 1e-6


# --- the pair mapping's Jacobian ------------------------------------------------------------

def test_pair_mapping_jacobian_of_a_sheared_mapping():
    """d(b line, b column) / d(a line, a column) of a sheared, rotated and scaled mapping: the
    analytic matrix, and central differences of the mapping itself (1e-6 relative: the mapping
    is bilinear between grid nodes, exact for an affine map)."""
    A = np.array([[0.97, 0.35], [-0.12, 1.08]])  # shear: A is far from symmetric
    model = AffineModel(A, np.array([5.0, -7.0]), np.array([0.01, 0.002]))
    raster = ArrayRaster(np.zeros((400, 300)))
    pm = PairMapping(_image("a", raster, model), _image("b", raster, model), (0.0, 500.0))
    line, col = 123.4, 211.7
    jac = pm.jacobian(line, col)
    assert np.allclose(jac, A, rtol=1e-6, atol=1e-9), jac
    h = 0.5
    fd = np.empty((2, 2))
    for k, d in enumerate((np.array([h, 0.0]), np.array([0.0, h]))):
        bl_p, bc_p = pm.at_heights(line + d[0], col + d[1])
        bl_m, bc_m = pm.at_heights(line - d[0], col - d[1])
        mid = len(pm.heights) // 2
        fd[:, k] = [(bl_p[mid, 0] - bl_m[mid, 0]) / (2 * h), (bc_p[mid, 0] - bc_m[mid, 0]) / (2 * h)]
    assert np.allclose(jac, fd, rtol=1e-6, atol=1e-9), (jac, fd)


def test_correlation_through_a_sheared_mapping():
    """The template is found in an image sheared against it when correlation resamples with the
    mapping's Jacobian (a transposed Jacobian would resample with the wrong shear)."""
    import cv2

    base = _texture((200, 200), 3)
    A = np.array([[1.0, 0.3], [0.0, 1.0]])  # b line = a line + 0.3 a column
    # b(p) = base(A^-1 (p - t)): warp base into b's geometry
    t = np.array([-20.0, 0.0])
    ll, cc = np.meshgrid(np.arange(200.0), np.arange(200.0), indexing="ij")
    Ai = np.linalg.inv(A)
    src_l = Ai[0, 0] * (ll - t[0]) + Ai[0, 1] * (cc - t[1])
    src_c = Ai[1, 0] * (ll - t[0]) + Ai[1, 1] * (cc - t[1])
    b = cv2.remap(base.astype(np.float32), src_c.astype(np.float32), src_l.astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    model = AffineModel(A, t, np.zeros(2))
    pm = PairMapping(_image("a", ArrayRaster(base), model), _image("b", ArrayRaster(b), model), (0.0, 1.0))
    half = SETTINGS.template_half_px
    centre = np.array([100, 90])
    tpl = base[centre[0] - half:centre[0] + half + 1, centre[1] - half:centre[1] + half + 1].astype(np.float32)
    truth = A @ centre + t
    got = correlate(tpl, _image("b", ArrayRaster(b)), truth + np.array([1.2, -0.8]), pm.jacobian(100.0, 90.0), SETTINGS.min_ncc)
    assert got is not None and got[1] > 0.95
    assert np.allclose(got[0], truth, atol=0.05), (got, truth)


# --- tracks: linking and the spread check ---------------------------------------------------

def _pm(a: int, b: int, pa, pb) -> PairMatches:
    return PairMatches(a, b, np.array(pa, float), np.array(pb, float))


def test_two_features_10_px_apart_chained_into_one_track_are_dropped():
    """Image 0's features A and B (10 px apart) each match image 1's P and image 2's Q, and
    P matches Q: the component holds A and B, two different features; it is dropped whole."""
    A, B = [50.0, 50.0], [50.0, 60.0]
    P, Q = [70.0, 40.0], [30.0, 45.0]
    pairs = [_pm(0, 1, [A], [P]), _pm(0, 2, [B], [Q]), _pm(1, 2, [P], [Q])]
    tracks, dropped = link(pairs, 3, scale=2.0)
    assert dropped == 1 and tracks == []
    # the same chain with A and B one pixel apart is one feature seen twice: one track
    pairs = [_pm(0, 1, [A], [P]), _pm(0, 2, [[50.0, 51.0]], [Q]), _pm(1, 2, [P], [Q])]
    tracks, dropped = link(pairs, 3, scale=2.0)
    assert dropped == 0 and len(tracks) == 1 and sorted(tracks[0].members) == [0, 1, 2]


def test_link_radius_scales_with_the_decimation():
    """Two pairs' ends of one feature in image 1, 2.5 px apart (within 1.5 px x the decimation 2
    of the detection, beyond 1.5 px): one three-image track at decimation 2, two two-image
    tracks at decimation 1."""
    pairs = [_pm(0, 1, [[10.0, 10.0]], [[40.0, 40.0]]), _pm(1, 2, [[40.0, 42.5]], [[80.0, 80.0]])]
    tracks, dropped = link(pairs, 3, scale=2.0)
    assert dropped == 0 and [sorted(t.members) for t in tracks] == [[0, 1, 2]]
    assert np.allclose(tracks[0].members[1], [40.0, 41.25])
    tracks, _ = link(pairs, 3, scale=1.0)
    assert sorted(sorted(t.members) for t in tracks) == [[0, 1], [1, 2]]


# --- the epipolar check after correlation ---------------------------------------------------

def test_epipolar_check_removes_a_match_off_its_epipolar_line():
    """Matches scattered by 0.1 px about their epipolar lines (plus a smooth orientation error)
    and one 1 px off: the check removes that one alone and states a sigma near 0.1 px."""
    rng = np.random.default_rng(5)
    A = np.eye(2)
    model = AffineModel(A, np.array([3.0, 2.0]), np.array([0.0, 0.02]))  # epipolar lines along the columns
    raster = ArrayRaster(np.zeros((500, 500)))
    pm = PairMapping(_image("a", raster, model), _image("b", raster, model), (0.0, 500.0))
    ref = rng.uniform(20, 480, size=(200, 2))
    pos = ref @ A.T + np.array([3.0, 2.0]) + np.column_stack([rng.uniform(0, 500, 200) * 0.0, rng.uniform(0, 10, 200)])
    pos[:, 0] += 0.4 + 0.001 * ref[:, 1] + rng.normal(0, 0.1, 200)  # smooth error + matching scatter
    pos[17, 0] += 1.0
    keep, sigma, _resid = epipolar_check(ref, pos, pm, SETTINGS.search_px)
    assert not keep[17]
    assert keep.sum() >= 197
    assert 0.08 < sigma < 0.12


def test_epipolar_check_removes_matches_beyond_3_5_sigma_and_states_the_kept_scatter():
    """Matches scattered by 0.06 px (a real pair's precision) and eight 0.3-0.45 px off (5-7.5
    sigma, under half a pixel): those eight are removed and the stated sigma is the scatter of
    the rest (0.06 px), not raised by them (about 0.07 px with them kept): the scatter data
    snooping leaves, so an adjustment's sigma0 stays near 1 after snooping."""
    rng = np.random.default_rng(8)
    A = np.eye(2)
    model = AffineModel(A, np.array([3.0, 2.0]), np.array([0.0, 0.02]))
    raster = ArrayRaster(np.zeros((500, 500)))
    pm = PairMapping(_image("a", raster, model), _image("b", raster, model), (0.0, 500.0))
    ref = rng.uniform(20, 480, size=(400, 2))
    pos = ref @ A.T + np.array([3.0, 2.0]) + np.column_stack([np.zeros(400), rng.uniform(0, 10, 400)])
    pos[:, 0] += 0.4 + 0.001 * ref[:, 1] + rng.normal(0, 0.06, 400)
    off = np.arange(8) * 7
    pos[off, 0] += rng.choice([-1.0, 1.0], 8) * rng.uniform(0.3, 0.45, 8)
    keep, sigma, _resid = epipolar_check(ref, pos, pm, SETTINGS.search_px)
    assert not keep[off].any()
    assert keep.sum() >= 390
    assert 0.052 < sigma < 0.065, sigma


# --- detection on decimated windows: a blob at a known sub-pixel position -------------------

def _blob_raster(tmp_path, centre: tuple[float, float], sigma: float = 3.0, size: int = 160) -> Raster:
    ll, cc = np.meshgrid(np.arange(size, dtype=float), np.arange(size, dtype=float), indexing="ij")
    values = 500.0 + 30000.0 * np.exp(-((ll - centre[0]) ** 2 + (cc - centre[1]) ** 2) / (2 * sigma**2))
    path = tmp_path / "blob.tif"
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=1, dtype="uint16") as dst:
        dst.write(np.rint(values).astype(np.uint16), 1)
    return Raster.open(path)


@pytest.mark.parametrize("centre", [(80.0, 80.0), (77.3, 84.6)])
def test_decimated_detection_finds_a_blob_where_it_is(tmp_path, centre):
    """SIFT on a window read decimated by 2 (the default) finds a Gaussian blob (our convention:
    pixel centres at integers) within 0.2 px of its true position; so does full resolution.
    The decimated grid's pixel (i, j) is centred on full-resolution (2 i + 0.5, 2 j + 0.5):
    dropping that half pixel moves every feature by 0.5 px along both axes."""
    raster = _blob_raster(tmp_path, centre)
    try:
        image = _image("blob", raster)
        for k in (1, 2):
            pos = detect(image, 20, 20, 120, 120, k).pos
            assert len(pos), k
            err = np.hypot(*(pos - np.array(centre)).T)
            assert float(err.min()) < 0.2, (k, pos, centre)
    finally:
        raster.close()


# --- overlap and tile selection over the whole height range ---------------------------------

def test_segment_enters_box():
    lo, hi = np.array([0.0, 0.0]), np.array([99.0, 99.0])
    p0 = np.array([[-50.0, 50.0], [-50.0, 50.0], [-50.0, -10.0], [120.0, 120.0], [10.0, 10.0], [-5.0, 50.0], [np.nan, 1.0]])
    p1 = np.array([[150.0, 50.0], [-1.0, 50.0], [-10.0, -50.0], [120.0, -20.0], [20.0, 20.0], [-5.0, 60.0], [5.0, 5.0]])
    # through, short of it, outside, along a side outside, inside, still outside, not finite
    assert list(segment_enters_box(p0, p1, lo, hi)) == [True, False, False, False, True, False, False]
    # a corner cut: from left of the box to above it, passing the corner (0, 0) 1.4 px inside
    assert segment_enters_box(np.array([[2.0, -2.0]]), np.array([[-2.0, 4.0]]), lo, hi)[0]


def test_tiles_are_selected_when_some_height_brings_them_into_b():
    """Image b sees a's pixels 0.5 px further down per metre of height: over 0-2000 m the
    epipolar segment of a pixel is 1000 px long, and most of a lies in b only near the top of
    the range (b is a's lines 900-1300 at 2000 m). Every node that some height brings into b
    counts for the overlap and for tile selection, not only those inside at every height or
    at the middle one."""
    model = AffineModel(np.eye(2), np.array([-1000.0, 0.0]), np.array([0.5, 0.0]))
    a = _image("a", ArrayRaster(np.zeros((400, 400))), model)
    b = _image("b", ArrayRaster(np.zeros((400, 400))), model)
    pm = PairMapping(a, b, (0.0, 2000.0))
    # b line = a line - 1000 + 0.5 h: a line 0 is in b for h >= 2000, a line 399 for h >= 1202
    lines = np.array([0.0, 100.0, 200.0, 399.0, 399.0])
    assert list(pm.reaches_b(lines, np.full(5, 200.0))) == [True, True, True, True, True]
    assert pm.overlap_fraction() == pytest.approx(1.0)
    # the same geometry over a range below 1,200 m: a's pixels never reach b
    low = PairMapping(a, b, (0.0, 1100.0))
    assert not low.reaches_b(lines, np.full(5, 200.0)).any() and low.overlap_fraction() == 0.0
    # over 0-1,500 m (b line = a line - 250 at the top): a's lines from 250 onwards reach b
    mid = PairMapping(a, b, (0.0, 1500.0))
    got = mid.reaches_b(np.array([245.0, 255.0, 399.0]), np.full(3, 200.0))
    assert list(got) == [False, True, True]


def test_rpc_height_range_is_the_rpcs_whole_range():
    """Each RPC's height offset +- its height scale, joined: nothing is cut off, so terrain far
    from the offset (a plateau at 2,300 m of an RPC fitted over 0-2,610 m) is inside."""
    from types import SimpleNamespace

    rpcs = [SimpleNamespace(height_off=1305.0, height_scale=1305.0), SimpleNamespace(height_off=1200.0, height_scale=1300.0)]
    assert rpc_height_range(rpcs) == (-100.0, 2610.0)


# --- tracks verified in 3-D ----------------------------------------------------------------

class AlongTrackView:
    """A linear along-track stereo view of a local Cartesian frame (metres): line = (y + tilt z)
    / gsd, column = x / gsd, plus the orientation's error ``bias`` (pixels)."""

    def __init__(self, tilt: float, bias=(0.0, 0.0), gsd: float = 2.0):
        self.tilt, self.bias, self.gsd = tilt, np.asarray(bias, float), gsd

    def ground_to_image(self, xyz):
        xyz = np.atleast_2d(xyz)
        return (xyz[:, 1] + self.tilt * xyz[:, 2]) / self.gsd + self.bias[0], xyz[:, 0] / self.gsd + self.bias[1], None

    def image_to_ground(self, line, column, height_m=None):
        line, column = np.atleast_1d(line) - self.bias[0], np.atleast_1d(column) - self.bias[1]
        h = np.full(len(line), float(height_m))
        return np.column_stack([column * self.gsd, line * self.gsd - self.tilt * h, h])


def test_three_image_tracks_lose_their_blunders_along_the_epipolar_line():
    """Three views (tilts -0.3, 0, 0.3), 300 points on 0-500 m terrain, matching noise 0.1 px;
    the guiding orientation of the third view is off by (4, -3) px; five of its measurements
    are 2 px wrong along its epipolar line (the line axis: a height error no pairwise check
    sees). The 3-D check removes those five tracks' non-reference measurements and nothing
    else."""
    from solver.matching.verify import verify

    rng = np.random.default_rng(7)
    truth = [AlongTrackView(-0.3), AlongTrackView(0.0), AlongTrackView(0.3)]
    guide = [AlongTrackView(-0.3), AlongTrackView(0.0), AlongTrackView(0.3, bias=(-4.0, 3.0))]
    pts = np.column_stack([rng.uniform(0, 2000, 300), rng.uniform(0, 2000, 300), rng.uniform(0, 500, 300)])
    tracks = []
    for p in pts:
        t = {}
        for i, v in enumerate(truth):
            line, col, _ = v.ground_to_image(p[None, :])
            t[i] = np.array([line[0], col[0]]) + (rng.normal(0, 0.1, 2) if i else 0.0)
        tracks.append(t)
    blunders = [3, 50, 111, 200, 299]
    for k in blunders:
        tracks[k][2] = tracks[k][2] + np.array([2.0, 0.0])
    sigmas = [{0: 0.02, 1: 0.14, 2: 0.14} for _ in tracks]
    removed, bias, res = verify(tracks, sigmas, guide, (0.0, 500.0), [(1000, 1000)] * 3)
    assert [k for k, r in enumerate(removed) if r] == blunders
    assert all(removed[k] == {1, 2} for k in blunders)  # which of the two is wrong cannot be told
    # the third view's column bias is found (its line bias is partly a height: not checked)
    assert bias[2, 0, 1] == pytest.approx(-3.0, abs=0.05)  # the shift at the image's centre
    kept = np.array([r[i] for k, r in enumerate(res) for i in r if k not in blunders])
    assert float(np.sqrt(np.mean(kept**2))) < 0.3  # the noise of three measurements, propagated


@pytest.mark.parametrize("true_px", [(0.1, 0.25), (0.3, 0.06)])
def test_stated_sigmas_are_calibrated_on_the_3d_residuals(true_px):
    """Three views, 1,000 points, the reference pixel exact (it defines the point), the two
    others' matching noise ``true_px`` (line and column each); the stated sigmas say 0.05 px
    for both (2 to 6 times too small, or too large). Each image's stated sigma times its factor
    is its true noise within 15 % (the estimate's own scatter over seeds: 3-6 %; measured here
    0.8-4.8 % off); an image with too few measurements in three-image tracks keeps its stated
    sigma."""
    from solver.matching.verify import image_bias, sigma_scales

    rng = np.random.default_rng(1)
    views = [AlongTrackView(-0.3), AlongTrackView(0.0), AlongTrackView(0.3)]
    pts = np.column_stack([rng.uniform(0, 2000, 1000), rng.uniform(0, 2000, 1000), rng.uniform(0, 500, 1000)])
    noise = (0.0, *true_px)
    tracks = []
    for p in pts:
        t = {}
        for i, v in enumerate(views):
            line, col, _ = v.ground_to_image(p[None, :])
            t[i] = np.array([line[0], col[0]]) + rng.normal(0, noise[i], 2)
        tracks.append(t)
    stated = [{0: 0.02, 1: 0.05, 2: 0.05} for _ in tracks]
    sizes = [(1000, 1000)] * 3
    bias = image_bias(tracks, views, (0.0, 500.0), sizes)
    scale = sigma_scales(tracks, stated, views, (0.0, 500.0), bias, sizes)
    assert scale[0] == 1.0  # the reference: never a non-reference measurement
    assert 0.05 * scale[1] == pytest.approx(true_px[0], rel=0.15) and 0.05 * scale[2] == pytest.approx(true_px[1], rel=0.15), scale
    few = sigma_scales(tracks[:19], stated[:19], views, (0.0, 500.0), bias, sizes)
    assert list(few) == [1.0, 1.0, 1.0]


def test_two_image_tracks_are_not_judged_in_3d():
    from solver.matching.verify import verify

    views = [AlongTrackView(-0.3), AlongTrackView(0.3)]
    tracks = [{0: np.array([100.0, 100.0]), 1: np.array([160.0, 100.0])}]  # any height explains it
    removed, _bias, _res = verify(tracks, [{0: 0.02, 1: 0.1}], views, (0.0, 500.0), [(1000, 1000)] * 2)
    assert removed == [set()]


def test_small_image_windows_are_the_files_pixels(tmp_path):
    """A small image is read whole once and its windows sliced: each window (clipped where it
    leaves the image) holds the file's own pixels at its offset (independent evidence: the values
    written), in our convention (array index = line - row0, column - col0)."""
    values = np.arange(70 * 90, dtype=np.uint16).reshape(70, 90) * 7  # every pixel distinct
    path = tmp_path / "small.tif"
    with rasterio.open(path, "w", driver="GTiff", width=90, height=70, count=1, dtype="uint16") as dst:
        dst.write(values, 1)
    raster = Raster.open(path)
    try:
        for r0, c0, rows, cols in [(10, 20, 25, 31), (0, 0, 70, 90), (60, 80, 25, 25), (-5, -3, 12, 9), (3, 4, 1, 1)]:
            got = raster.window(r0, c0, rows, cols)
            want = values[max(r0, 0):min(r0 + rows, 70), max(c0, 0):min(c0 + cols, 90)].astype(np.float32)
            assert got.dtype == np.float32 and got.shape == want.shape, (r0, c0, got.shape, want.shape)
            assert np.max(np.abs(got - want)) < 0.5, (r0, c0)
        assert raster.window(80, 0, 5, 5).size == 0
    finally:
        raster.close()


# --- features detected once per image, the strongest of each cell ----------------------------

def _textured_raster(tmp_path, size: int = 640) -> Raster:
    path = tmp_path / "texture.tif"
    values = _texture((size, size), 21)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=1, dtype="uint16") as dst:
        dst.write(np.clip(values, 0, 65535).astype(np.uint16), 1)
    return Raster.open(path)


def test_features_are_detected_once_and_agree_with_a_whole_image_detection(tmp_path):
    """The cache detects a block the first time a window needs it and never again; its features
    are those SIFT finds in the whole image at once (the blocks' margins give every feature its
    context): at least 99 % of either set has the other's within 0.01 px."""
    from scipy.spatial import cKDTree

    from solver.matching.keypoints import BLOCK_PX, FeatureCache

    raster = _textured_raster(tmp_path)
    try:
        image = _image("t", raster)
        cache = FeatureCache(image, 2, whole=False)  # a large image's path (this one is small enough to be detected whole)
        first = cache.window(np.array([0, 0]), np.array([300, 300]))
        calls = cache.detections
        again = cache.window(np.array([100, 100]), np.array([300, 300]))
        assert cache.detections == calls == 1
        inside = np.all((first.pos >= 100) & (first.pos < 300), axis=1)
        assert np.array_equal(again.pos, first.pos[inside]) and np.array_equal(again.desc, first.desc[inside])
        cache = FeatureCache(image, 2, whole=False)  # block by block: every block detected on its own
        for i in range(0, 640, BLOCK_PX):
            for j in range(0, 640, BLOCK_PX):
                cache.window(np.array([i, j]), np.array([i + BLOCK_PX, j + BLOCK_PX]))
        assert cache.detections == (-(-640 // BLOCK_PX)) ** 2
        blocks = cache.window(np.array([0, 0]), np.array([640, 640]))
        whole = detect(image, 0, 0, 640, 640, 2)
        assert len(blocks) > 500
        d_bw, _ = cKDTree(whole.pos).query(blocks.pos)
        d_wb, _ = cKDTree(blocks.pos).query(whole.pos)
        # measured: 99.96 % both ways (without the margins: 95.7 % and 88.0 %)
        assert np.mean(d_bw < 0.01) > 0.99 and np.mean(d_wb < 0.01) > 0.99, (np.mean(d_bw < 0.01), np.mean(d_wb < 0.01))
    finally:
        raster.close()


def test_an_image_in_its_last_pair_keeps_only_recent_blocks(tmp_path):
    """After keep_recent(1), a window far away lets the first window's blocks go (memory); asked
    for again, they are detected again, with the same features."""
    from solver.matching.keypoints import BLOCK_PX, FeatureCache

    raster = _textured_raster(tmp_path)
    n = 128 // BLOCK_PX  # blocks per side of the first window
    try:
        cache = FeatureCache(_image("t", raster), 2, whole=False)
        cache.keep_recent(1)
        lo, hi = np.array([0, 0]), np.array([128, 128])
        first = cache.window(lo, hi)
        cache.window(np.array([512, 512]), np.array([640, 640]))
        assert not any(i < n and j < n for i, j in cache.blocks)  # the first window's blocks are gone
        calls = cache.detections
        again = cache.window(lo, hi)
        assert cache.detections == calls + 1
        assert np.array_equal(again.pos, first.pos) and np.array_equal(again.desc, first.desc)
        assert cache.detected_fraction() == pytest.approx(8 / 100)  # the two 128 px windows: 2 x 4 % of the 640 px image, counted once
        # an image read only through its a tiles from now on keeps only those tiles' blocks
        cache.retain([(np.array([0, 0]), np.array([BLOCK_PX, BLOCK_PX]))])
        assert sorted(cache.blocks) == [(0, 0)]
        corner = cache.window(np.array([0, 0]), np.array([BLOCK_PX, BLOCK_PX])).pos
        assert np.array_equal(corner, first.pos[np.all(first.pos < BLOCK_PX, axis=1)])
    finally:
        raster.close()


def test_a_small_image_is_detected_in_strips_once_and_split_into_its_blocks(tmp_path):
    """A small image (the raster holds it whole) is detected in whole-width strips of
    STRIP_BLOCKS rows of blocks, each read with MARGIN_PX above and below, the first time a
    window needs one of its blocks: a window's features are those strips' own (the features of
    each strip's detection in the strip's blocks), and every block is kept (never detected
    again) in its last pair and when an image keeps only its a tiles."""
    from solver.matching.keypoints import BLOCK_PX, MARGIN_PX, STRIP_BLOCKS, FeatureCache

    raster = _textured_raster(tmp_path)
    try:
        image = _image("t", raster)
        cache = FeatureCache(image, 2)
        assert cache.whole
        cache.keep_recent(1)
        part = cache.window(np.array([100, 200]), np.array([228, 328]))
        rows_px = BLOCK_PX * STRIP_BLOCKS
        strips = range(100 // rows_px, (228 - 1) // rows_px + 1)
        assert cache.detections == len(strips) == 2

        def strip_features(k):
            f = detect(image, k * rows_px - MARGIN_PX, -MARGIN_PX, rows_px + 2 * MARGIN_PX, 640 + 2 * MARGIN_PX, 2)
            return f.take(np.flatnonzero((f.pos[:, 0] >= k * rows_px) & (f.pos[:, 0] < (k + 1) * rows_px)))

        own = Features.concat([strip_features(k) for k in strips])
        inside = np.all((own.pos >= [100, 200]) & (own.pos < [228, 328]), axis=1)
        assert _rows(part) == _rows(own.take(np.flatnonzero(inside)))
        everything = cache.window(np.array([0, 0]), np.array([640, 640]))
        n_strips = -(-640 // rows_px)
        assert cache.detections == n_strips and cache.detected_fraction() == 1.0
        assert _rows(everything) == _rows(Features.concat([strip_features(k) for k in range(n_strips)]))
        cache.window(np.array([512, 512]), np.array([640, 640]))
        cache.retain([(np.array([0, 0]), np.array([32, 32]))])
        cache.window(np.array([100, 200]), np.array([228, 328]))
        assert cache.detections == n_strips and len(cache.blocks) == cache.shape[0] * cache.shape[1]
    finally:
        raster.close()


@pytest.mark.parametrize("k", [1, 2])
def test_the_context_of_a_window_gets_no_descriptors_and_leaves_its_features_as_they_are(tmp_path, k):
    """detect(..., inner=(lo, hi)) computes descriptors only near [lo, hi) (the rest of the read
    is context) and gives exactly the features a detection of the whole read finds there, also
    for features within a pixel of the inner rectangle's edges (OpenCV tests a feature's
    nearest pixel against the mask): inner rectangles at arbitrary offsets, many features on
    their edges."""
    raster = _textured_raster(tmp_path)
    rng = np.random.default_rng(5)
    try:
        image = _image("t", raster)
        near_edge = 0
        for _ in range(12):
            r0, c0 = (int(v) for v in rng.integers(0, 200, 2))
            rows, cols = (int(v) for v in rng.integers(200, 400, 2))
            lo = np.array([r0, c0]) + rng.uniform(20, 60, 2)
            hi = np.array([r0 + rows, c0 + cols]) - rng.uniform(20, 60, 2)
            full = detect(image, r0, c0, rows, cols, k)
            masked = detect(image, r0, c0, rows, cols, k, inner=(lo, hi))

            def within(f, lo=lo, hi=hi):
                return f.take(np.flatnonzero(np.all((f.pos >= lo) & (f.pos < hi), axis=1)))

            assert _rows(within(masked)) == _rows(within(full))
            assert len(masked) < 0.8 * len(full)  # the context's features are dropped ...
            outside = np.maximum(np.maximum(lo - masked.pos, masked.pos - hi), 0).max(axis=1)
            assert outside.max() <= 1.5 * k  # ... all but those of the pixels on the edge
            edge = np.minimum(np.abs(full.pos - lo), np.abs(full.pos - hi)).min(axis=1)
            near_edge += int(np.sum(edge < 0.5 * k))
        assert near_edge >= 10  # the edges were tested
    finally:
        raster.close()


def test_sift_gives_the_same_features_on_one_and_on_two_opencv_threads():
    """OpenCV's threads inside a SIFT call (match_images sets PBA_MATCH_THREADS of them) do
    not change its features: positions, responses and descriptors identical."""
    import cv2

    from solver.matching.keypoints import sift

    t = _texture((300, 420), 9)
    image8 = np.clip(128 + 40 * (t - t.mean()) / t.std(), 0, 255).astype(np.uint8)
    previous = cv2.getNumThreads()
    try:
        cv2.setNumThreads(1)
        one = sift(image8)
        cv2.setNumThreads(2)
        two = sift(image8)
    finally:
        cv2.setNumThreads(previous)
    assert len(one) > 200
    assert _rows(one) == _rows(two)


def _rows(f) -> list[tuple]:
    """A window's features as sorted rows (position, response, descriptor): the same set."""
    return sorted((*p, r, d.tobytes()) for p, r, d in zip(f.pos.tolist(), f.response.tolist(), f.desc, strict=True))


def _tile_windows(size: int, side: int, step: int) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(np.array([i, j]), np.array([i + side, j + side])) for i in range(0, size - side + 1, step) for j in range(0, size - side + 1, step)]


@pytest.mark.parametrize("whole", [False, True])
def test_detection_ahead_in_a_thread_gives_the_sequential_features(tmp_path, whole):
    """Windows detected ahead in the pool's thread (as match_pair announces a's tiles) give the
    same features as the sequential path, window for window and block for block, also when
    earlier windows of other shapes left some blocks detected (other rectangles to detect) and
    when the main thread gets to a window first. Exact equality: the same SIFT call on the same
    read, single-threaded, so the same result (any difference is a wrong prefetch)."""
    from concurrent.futures import wait

    from solver.matching.keypoints import FeatureCache, detection_pool

    raster = _textured_raster(tmp_path)
    # windows in a b role first (a large image: blocks left detected, so other rectangles to
    # detect); a small image's first window detects it whole, so it is one of the tiles
    earlier = [] if whole else [(np.array([40, 300]), np.array([250, 420])), (np.array([400, 0]), np.array([460, 640]))]
    tiles = _tile_windows(640, 160, 96)  # overlapping tiles: blocks shared between neighbours
    try:
        image = _image("t", raster)
        sequential = FeatureCache(image, 2, whole=whole)
        expected = [sequential.window(lo, hi) for lo, hi in earlier + tiles]
        with detection_pool(2) as pool:
            for waiting in (True, False):  # prefetched detections all used; then the main thread racing the pool's
                cache = FeatureCache(image, 2, pool, whole=whole)
                got = [cache.window(lo, hi) for lo, hi in earlier]
                used = 0
                for n, (lo, hi) in enumerate(tiles):
                    for ahead in tiles[n:n + 3]:
                        cache.prefetch(*ahead)
                    if waiting:
                        wait(list(cache.pending.values()))
                        used += len(cache.pending)
                    got.append(cache.window(lo, hi))
                assert not cache.pending and not cache.planned  # every detection started ahead was used
                if waiting:
                    assert used > 0 and cache.detections == sequential.detections
                for g, e in zip(got, expected, strict=True):
                    assert np.array_equal(g.pos, e.pos) and np.array_equal(g.desc, e.desc) and np.array_equal(g.response, e.response)
                assert sorted(cache.blocks) == sorted(sequential.blocks)
                for key, f in sequential.blocks.items():
                    assert np.array_equal(cache.blocks[key].pos, f.pos) and np.array_equal(cache.blocks[key].desc, f.desc)
    finally:
        raster.close()


def test_match_threads_setting(monkeypatch):
    """PBA_MATCH_THREADS: a positive integer; by default 2, or the cores available if fewer."""
    import os

    from solver.matching.keypoints import THREADS_ENV, match_threads

    monkeypatch.setenv(THREADS_ENV, "1")
    assert match_threads() == 1
    monkeypatch.setenv(THREADS_ENV, " 3 ")
    assert match_threads() == 3
    for bad in ("0", "-2", "two"):
        monkeypatch.setenv(THREADS_ENV, bad)
        with pytest.raises(ValueError, match=THREADS_ENV):
            match_threads()
    monkeypatch.delenv(THREADS_ENV)
    assert match_threads() == min(2, len(os.sched_getaffinity(0)))


def test_each_cell_keeps_its_strongest_features():
    """n strongest per cell, whatever the other cells hold: a cell of weak features keeps its own
    (a strongest-of-the-tile choice would leave it empty)."""
    from solver.matching.features import strongest_per_cell
    from solver.matching.keypoints import Features

    rng = np.random.default_rng(4)
    pos = rng.uniform(0, 400, (500, 2))
    response = rng.uniform(0, 1, 500).astype(np.float32)
    weak = (pos[:, 0] < 100) & (pos[:, 1] < 100)  # cell (0, 0) of a 4 x 4 grid
    response[weak] *= 1e-3
    f = Features(pos, np.zeros((500, 128), np.uint8), response)
    kept = strongest_per_cell(f, 400, 400, 4, 3)
    cells = (pos[:, 0] // 100).astype(int) * 4 + (pos[:, 1] // 100).astype(int)
    expected = []
    for c in range(16):
        members = np.flatnonzero(cells == c)
        expected += list(members[np.argsort(-response[members])[:3]])
    assert sorted(map(tuple, kept.pos)) == sorted(map(tuple, pos[expected]))
    assert np.sum(np.all(kept.pos < 100, axis=1)) == 3


def test_union_find_over_arrays_finds_the_connected_components():
    """The components of random graphs (chains, stars, isolated nodes) are those scipy finds."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from solver.matching.tracks import components

    rng = np.random.default_rng(9)
    for n, m in ((1, 0), (50, 10), (2000, 1500), (2000, 3000)):
        edges = rng.integers(0, n, (m, 2))
        chain = np.column_stack([np.arange(min(n, 300) - 1), np.arange(1, min(n, 300))])[::-1]  # a long chain, given backwards
        edges = np.vstack([edges, chain]).astype(int)
        label = components(n, edges)
        _k, expected = connected_components(coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)), directed=False)
        # the same partition: a one-to-one map between the labels
        pairs = set(zip(label.tolist(), expected.tolist(), strict=True))
        assert len(pairs) == len(set(label.tolist())) == len(set(expected.tolist()))
        assert all(label[i] <= i for i in range(n))  # each label is a node of its component (the smallest)


# --- each tile's height range -------------------------------------------------------------

PARALLAX_MODEL = AffineModel(np.eye(2), np.array([-3.0, 7.0]), np.array([0.5, 0.2]))  # b = a + t + h (0.5, 0.2)


def test_positions_at_a_height_and_the_height_of_a_match():
    """``at_height`` agrees with the model at heights inside and beyond the grid's range, and
    ``height_of`` gives back the height a b position was made at (from the model itself)."""
    raster = ArrayRaster(np.zeros((400, 400)))
    pm = PairMapping(_image("a", raster, PARALLAX_MODEL), _image("b", raster, PARALLAX_MODEL), (0.0, 1000.0))
    rng = np.random.default_rng(3)
    pa = rng.uniform(0, 399, (50, 2))
    h = rng.uniform(-200.0, 1200.0, 50)
    truth = np.column_stack(PARALLAX_MODEL.ground_to_image(np.column_stack([pa, h]))[:2])
    assert np.allclose(pm.at_height(pa[:, 0], pa[:, 1], h), truth, atol=1e-6)
    inside = (h >= 0) & (h <= 1000)
    across = np.array([-0.2, 0.5]) / np.hypot(0.2, 0.5) * 0.3  # 0.3 px off the epipolar line
    assert np.allclose(pm.height_of(pa[inside], truth[inside] + across), h[inside], atol=1e-6)
    assert np.allclose(pm.height_of(pa[~inside], truth[~inside]), np.clip(h[~inside], 0.0, 1000.0), atol=1e-6)


def _tile_heights(size: int = 4096, heights=(0.0, 2000.0), terrain=None):
    from solver.matching.features import TileHeights

    raster = ArrayRaster(np.zeros((size, size)))
    pm = PairMapping(_image("a", raster, PARALLAX_MODEL), _image("b", raster, PARALLAX_MODEL), heights)
    return TileHeights(pm.a, pm, SETTINGS, terrain)


def test_a_tile_is_searched_over_its_neighbours_heights_with_a_margin():
    """Over 0-2,000 m the band is 1,077 px long; a tile next to a matched tile whose matches lie
    at 500-520 m is searched over that range widened by 32 px of band (59.4 m) each side; a tile
    with no matched neighbour, the whole range; a tile left, above or above right of nothing
    matched too."""
    from solver.matching.features import NARROW_MARGIN_PX, Tile

    th = _tile_heights()
    t = Tile(np.zeros(2), np.full(2, 256.0), ((0, 0),))
    assert th.of(0, t) is None
    th.found_at(0, np.linspace(500.0, 520.0, 20))
    m = NARROW_MARGIN_PX * 2000.0 / (2000.0 * np.hypot(0.5, 0.2))
    for n in (1, 16, 17):  # right of it, below it, below right
        lo, hi = th.of(n, t)
        assert lo == pytest.approx(500.0 - m) and hi == pytest.approx(520.0 + m)
    assert th.of(2, t) is None and th.of(18, t) is None and th.of(32, t) is None
    th.found_at(2, np.linspace(900.0, 1000.0, 20))  # a steeper neighbour: a quarter of the spread
    lo, hi = th.of(17, t)
    assert lo == pytest.approx(500.0 - 125.0) and hi == pytest.approx(1000.0 + 125.0)
    # too few matches to tell a range
    th.found_at(40, np.linspace(0.0, 10.0, 9))
    assert th.of(41, t) is None


def test_a_narrowed_tile_with_few_matches_is_searched_again():
    from solver.matching.features import Tile

    th = _tile_heights()
    assert th.retry(9) and not th.retry(10)
    dem = _tile_heights(terrain=lambda image, lo, hi: (100.0, 200.0))
    assert dem.of(5, Tile(np.zeros(2), np.full(2, 256.0), ((0, 5),))) == (100.0, 200.0) and not dem.retry(0)  # the DEM is the evidence: no second search


def test_tiles_keep_the_whole_range_where_narrowing_cannot_pay():
    """A short band (0-200 m: 108 px) or an image of small cells (detected whole anyway)."""
    from solver.matching.features import Tile

    t = Tile(np.zeros(2), np.full(2, 256.0), ((0, 0),))
    for th in (_tile_heights(heights=(0.0, 200.0)), _tile_heights(size=1024)):
        th.found_at(0, np.linspace(50.0, 60.0, 20))
        assert th.of(1, t) is None


def test_dem_heights_under_a_tile():
    """A DEM whose height is 200 m + 1 m per column of the image (the image's longitude is its
    column x 1e-5 degrees): the tile of columns 100-199 gets 300-399 m +- 50 m."""
    from types import SimpleNamespace

    from solver.geometry.geodesy import geodetic_to_ecef
    from solver.matching.heights import DEM_MARGIN_M, DemHeights

    class LonLatModel:
        def image_to_ground(self, line, column, height_m=None):
            line, column = np.atleast_1d(line), np.atleast_1d(column)
            return geodetic_to_ecef(np.column_stack([10.0 + column * 1e-5, 45.0 - line * 1e-5, np.full(len(line), float(height_m))]))

    dem = SimpleNamespace(cell_m=0.5, height=lambda lon, lat: 200.0 + (np.asarray(lon) - 10.0) * 1e5)
    got = DemHeights(dem, (0.0, 1000.0))(_image("a", None, LonLatModel()), np.array([0.0, 100.0]), np.array([50.0, 200.0]))
    assert got[0] == pytest.approx(300.0 - DEM_MARGIN_M, abs=1.0) and got[1] == pytest.approx(399.0 + DEM_MARGIN_M, abs=1.0)


def test_close_pairs_are_every_pair_within_the_radius():
    from solver.matching.tracks import close_pairs

    rng = np.random.default_rng(5)
    pos = rng.uniform(0, 60, (400, 2))
    pos[::10] = pos[1::10] + 0.5  # near duplicates
    pos[5] = pos[6] + [2.999, 0.0]  # just inside the radius
    pos[7] = pos[8] + [0.0, 3.001]  # just outside
    d = np.hypot(*(pos[:, None, :] - pos[None, :, :]).T)
    want = {(i, j) for i, j in zip(*np.nonzero(d <= 3.0), strict=True) if i < j}
    got = close_pairs(pos, 3.0)
    assert len(got) == len(want) and {tuple(p) for p in got.tolist()} == want
