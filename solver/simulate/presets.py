"""Ready-made simulations (``pba simulate PRESET``).

- ``prism-single``: one PRISM-like scene (backward, nadir or forward camera), 14 gcp / 9 check
  by default (seed 000);
- ``prism-triplet``: backward, nadir and forward images of the same area, 22 gcp, 20 check and
  40 tie points, every point in all three images (seed 001);
- ``cbers-scene``: one CBERS-like CCD scene (~20 m GSD, 778 km orbit) with ground coordinates in
  SAD69 / UTM zone 22S (EPSG:29192), 23 gcp and 8 check points (seed 002);
- ``strip``: N consecutive PRISM triplets along one pass with M tie points in total, each seen
  in the three images of its triplet (large blocks for the solver benchmark);
- ``small-triplet``: a backward / nadir / forward triplet of a small single-chip camera (20 m
  ground pixels, N x N pixels, views 20 degrees apart, terrain 200-1200 m): rasters of a few
  hundred pixels a side for trying image matching and RPC images in seconds.
"""

from __future__ import annotations

from dataclasses import replace

from solver.simulate.camera import cbers_camera, prism_camera, simple_camera
from solver.simulate.scene import Group, Scene, SceneSettings

PRISM_VIEWS = ("backward", "nadir", "forward")
CBERS_SITE = (-51.147, -22.372)  # centre of the seed 002 scene (orbit 159, point 125)
CBERS_INCLINATION_DEG = 98.5
# small-triplet: a CBERS-like detector (f 520 mm, 13 um pixels, 2.92 ms lines: ~20 m ground
# pixels from the ALOS-like orbit) pitched back, down and forward; terrain with ~1 km of relief,
# so the views differ by up to ~20 px of parallax (what image matching must follow)
SMALL_VIEWS_DEG = (("back", -20.0), ("nadir", 0.0), ("fwd", 20.0))
SMALL_TERRAIN_M = (200.0, 1200.0)
SMALL_MIN_PX = 64


def prism_single(
    settings: SceneSettings, camera: str = "nadir", gcps: int = 14, checks: int = 9, chip_layout: str = "partition"
) -> Scene:
    """One PRISM-like image of the default area (``chip_layout``: :func:`solver.simulate.camera.prism_chips`)."""
    group = Group([prism_camera(camera, chip_layout)], gcps, checks, 0)
    return Scene(replace(settings, preset="prism-single"), [group]).simulate()


def prism_triplet(
    settings: SceneSettings, gcps: int = 22, checks: int = 20, tie_points: int = 40, chip_layout: str = "partition"
) -> Scene:
    """A PRISM-like triplet (backward, nadir, forward) of the default area (``chip_layout``:
    :func:`solver.simulate.camera.prism_chips`)."""
    group = Group([prism_camera(v, chip_layout) for v in PRISM_VIEWS], gcps, checks, tie_points)
    return Scene(replace(settings, preset="prism-triplet"), [group]).simulate()


def cbers_scene(settings: SceneSettings, gcps: int = 23, checks: int = 8) -> Scene:
    """A CBERS-like CCD scene, ground coordinates in SAD69 / UTM 22S."""
    s = replace(
        settings,
        preset="cbers-scene",
        lon_deg=CBERS_SITE[0],
        lat_deg=CBERS_SITE[1],
        inclination_deg=CBERS_INCLINATION_DEG,
        crs="EPSG:29192",
        epoch_s=48600.0 if settings.epoch_s == SceneSettings.epoch_s else settings.epoch_s,
    )
    return Scene(s, [Group([cbers_camera()], gcps, checks, 0)]).simulate()


def strip(
    settings: SceneSettings, triplets: int = 20, tie_points: int = 30000, gcps: int | None = None, checks: int | None = None
) -> Scene:
    """``triplets`` consecutive PRISM triplets along one pass, ``tie_points`` ties in total.

    Control defaults to 4 gcp and 2 check points per triplet; totals are spread evenly.
    """
    if triplets < 1:
        raise ValueError("at least one triplet")
    gcps = 4 * triplets if gcps is None else gcps
    checks = 2 * triplets if checks is None else checks

    def share(total: int, k: int) -> int:
        return total // triplets + (1 if k < total % triplets else 0)

    groups = [
        Group([prism_camera(v) for v in PRISM_VIEWS], share(gcps, k), share(checks, k), share(tie_points, k))
        for k in range(triplets)
    ]
    return Scene(replace(settings, preset="strip", truth_step_lines=max(settings.truth_step_lines, 1000)), groups).simulate()


def small_triplet(settings: SceneSettings, size_px: int = 480, gcps: int = 8, checks: int = 8, tie_points: int = 30) -> Scene:
    """Three views (``back``, ``nadir``, ``fwd``: pitched -20, 0, +20 degrees) of a
    ``size_px`` x ``size_px`` single-chip camera with ~20 m ground pixels over terrain of
    200-1200 m ellipsoidal height."""
    if size_px < SMALL_MIN_PX:
        raise ValueError(f"size {size_px}: at least {SMALL_MIN_PX} pixels")
    cams = [simple_camera(name, 520.0, 0.013, 0.00292, size_px, size_px, pitch) for name, pitch in SMALL_VIEWS_DEG]
    low, high = SMALL_TERRAIN_M
    s = replace(settings, preset="small-triplet", terrain_min_m=low, terrain_max_m=high)
    return Scene(s, [Group(cams, gcps, checks, tie_points)]).simulate()
