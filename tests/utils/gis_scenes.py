"""Simulated scenes adjusted once per test process, for the GIS tests (tests/solver/gis/test_gis_*.py).

Small single-chip scenes (a CBERS-like 20 m camera, 2400 x 2400 pixels, nadir or tilted 20 deg
along track) with every platform-model kind, and one PRISM-like 4-chip image; each is simulated,
written as a job, adjusted by the solver, and its job + report give the adjusted model.
"""

from __future__ import annotations

from functools import lru_cache

from solver import api
from solver.gis.model import AdjustedModel, load_model
from solver.simulate import presets
from solver.simulate.camera import simple_camera
from solver.simulate.scene import Group, Scene, SceneSettings

# one model name per platform kind (solver.platforms.kinds)
MODEL_KINDS = {"polynomial": "P2", "kepler": "J2-2", "orbit-attitude": "OA-J2", "pass": "PASS-J2"}
VIEWS = {"nadir": 0.0, "tilted": 20.0}


@lru_cache(maxsize=None)
def single_chip(model: str, pitch_deg: float = 0.0, seed: int = 5) -> tuple[Scene, dict, dict, AdjustedModel]:
    """(scene, job, report, adjusted model) of one single-chip image."""
    cam = simple_camera("cam", 520.0, 0.013, 0.00292, 2400, 2400, pitch_deg)
    settings = SceneSettings(preset="gis-test", seed=seed, name=f"gis {model} {pitch_deg}", model=model, noise_px=0.05)
    scene = Scene(settings, [Group([cam], 16, 8, 0)]).simulate()
    job = scene.job()
    report = api.run(job)
    return scene, job, report, load_model(job, report)


@lru_cache(maxsize=None)
def prism_butted(view: str = "nadir", seed: int = 5) -> tuple[Scene, dict, dict, AdjustedModel]:
    """(scene, job, report, adjusted model) of one PRISM-like image with four butted chips."""
    settings = SceneSettings(preset="prism-single", seed=seed, name=f"gis prism {view}", model="OA-J2", noise_px=0.05)
    scene = presets.prism_single(settings, view, 14, 9, "butted")
    job = scene.job()
    report = api.run(job)
    return scene, job, report, load_model(job, report)


@lru_cache(maxsize=None)
def two_chip(seed: int = 5) -> tuple[Scene, dict, dict, AdjustedModel]:
    """A small PRISM-like camera (2.5 m GSD, 3000 x 2400 pixels) with two chips side by side,
    0.021 mm (3 px) apart along track: (scene, job, report, adjusted model)."""
    from solver.simulate.camera import CameraSpec, chips_partition

    chips = chips_partition((1200, 1200), 0.007, (-0.0107, 0.0107), (0.0009, -0.0008))
    cam = CameraSpec("mc", 1939.0, 0.007, 0.00037, 3000, 2400, chips, 0.0)
    settings = SceneSettings(preset="gis-test", seed=seed, name="gis two chips", model="OA-J2", noise_px=0.05)
    scene = Scene(settings, [Group([cam], 16, 8, 0)]).simulate()
    job = scene.job()
    report = api.run(job)
    return scene, job, report, load_model(job, report)
