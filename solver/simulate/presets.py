"""Ready-made simulations (``pba simulate PRESET``).

- ``prism-single``: one PRISM-like scene (backward, nadir or forward camera), 14 gcp / 9 check
  by default (seed 000);
- ``prism-triplet``: backward, nadir and forward images of the same area, 22 gcp, 20 check and
  40 tie points, every point in all three images (seed 001);
- ``cbers-scene``: one CBERS-like CCD scene (~20 m GSD, 778 km orbit) with ground coordinates in
  SAD69 / UTM zone 22S (EPSG:29192), 23 gcp and 8 check points (seed 002);
- ``strip``: N consecutive PRISM triplets along one pass with M tie points in total, each seen
  in the three images of its triplet (large blocks for the solver benchmark).
"""

from __future__ import annotations

from dataclasses import replace

from solver.simulate.camera import cbers_camera, prism_camera
from solver.simulate.scene import Group, Scene, Settings

PRISM_VIEWS = ("backward", "nadir", "forward")
CBERS_SITE = (-51.147, -22.372)  # centre of the seed 002 scene (orbit 159, point 125)
CBERS_INCLINATION_DEG = 98.5


def prism_single(
    settings: Settings, camera: str = "nadir", gcps: int = 14, checks: int = 9, chip_layout: str = "partition"
) -> Scene:
    """One PRISM-like image of the default area (``chip_layout``: :func:`solver.simulate.camera.prism_chips`)."""
    group = Group([prism_camera(camera, chip_layout)], gcps, checks, 0)
    return Scene(replace(settings, preset="prism-single"), [group]).simulate()


def prism_triplet(
    settings: Settings, gcps: int = 22, checks: int = 20, tie_points: int = 40, chip_layout: str = "partition"
) -> Scene:
    """A PRISM-like triplet (backward, nadir, forward) of the default area (``chip_layout``:
    :func:`solver.simulate.camera.prism_chips`)."""
    group = Group([prism_camera(v, chip_layout) for v in PRISM_VIEWS], gcps, checks, tie_points)
    return Scene(replace(settings, preset="prism-triplet"), [group]).simulate()


def cbers_scene(settings: Settings, gcps: int = 23, checks: int = 8) -> Scene:
    """A CBERS-like CCD scene, ground coordinates in SAD69 / UTM 22S."""
    s = replace(
        settings,
        preset="cbers-scene",
        lon_deg=CBERS_SITE[0],
        lat_deg=CBERS_SITE[1],
        inclination_deg=CBERS_INCLINATION_DEG,
        crs="EPSG:29192",
        epoch_s=48600.0 if settings.epoch_s == Settings.epoch_s else settings.epoch_s,
    )
    return Scene(s, [Group([cbers_camera()], gcps, checks, 0)]).simulate()


def strip(
    settings: Settings, triplets: int = 20, tie_points: int = 30000, gcps: int | None = None, checks: int | None = None
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
