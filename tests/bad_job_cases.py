"""Malformed jobs (mutations of examples/prism-triplet.json) and where each must be refused.

Shared by tests/test_bad_input.py (through solver.api) and tests/service/test_service_bad_input.py
(through the HTTP API); pytest puts this directory on sys.path (tests/conftest.py has no package).
Every case was answered 500 or accepted silently before issue 13. ``where`` is the location in
the job document (a tuple; the service prefixes ``/inputs/job``).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any, Callable

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "prism-triplet.json"
ELEMENTS = ("X", "Y", "Z", "omega", "phi", "kappa")


def triplet() -> dict[str, Any]:
    return json.loads(EXAMPLE.read_text())


def _set(path: tuple, value: Any) -> Callable[[dict[str, Any]], None]:
    def mutate(doc: dict[str, Any]) -> None:
        node = doc
        for key in path[:-1]:
            node = node.setdefault(key, {}) if isinstance(key, str) else node[key]
        node[path[-1]] = value

    return mutate


def _model(name: str, options: dict[str, Any]) -> Callable[[dict[str, Any]], None]:
    def mutate(doc: dict[str, Any]) -> None:
        for im in doc["images"]:
            im["model"] = {"name": name, "options": copy.deepcopy(options)}

    return mutate


def _weighted_iop(names: list[str], matrix: list[list[float]]) -> Callable[[dict[str, Any]], None]:
    def mutate(doc: dict[str, Any]) -> None:
        cam = doc["cameras"][0]
        cam["iop"] = {"df": 0.01}
        cam["iop_use"] = "weighted"
        cam["iop_covariance"] = {"names": names, "matrix": matrix}
        doc.setdefault("options", {})["self_calibration"] = {"estimate": ["df"]}

    return mutate


FOCAL = triplet()["cameras"][0]["focal_mm"]
STATE = ("images", 0, "approx_state")

# id -> (mutation, location that must be named)
CASES: dict[str, tuple[Callable[[dict[str, Any]], None], tuple]] = {
    "lines_1e400": (_set(("cameras", 0, "lines"), 10**400), ("cameras", 0, "lines")),
    "orders_as_list": (_model("GENERAL", {"orders": [50] * 6}), ("images", 0, "model", "options", "orders")),
    "orders_beyond_3": (_model("GENERAL", {"orders": {"X": 50}}), ("images", 0, "model", "options", "orders", "X")),
    "every_order_held": (
        _model("GENERAL", {"orders": {e: -1 for e in ELEMENTS}}),
        ("images", 0, "model", "options", "orders", "X"),
    ),
    "iop_df_string": (_set(("cameras", 0, "iop"), {"df": "abc"}), ("cameras", 0, "iop", "df")),
    "iop_df_minus_focal": (_set(("cameras", 0, "iop"), {"df": -FOCAL}), ("cameras", 0, "iop")),
    "iop_unknown_name": (_set(("cameras", 0, "iop"), {"a0@9": 0.001}), ("cameras", 0, "iop")),
    "state_at_geocentre": (_set((*STATE, "position_ecef_m"), [0, 0, 0]), (*STATE, "position_ecef_m")),
    "state_1e300": (_set((*STATE, "position_ecef_m"), [1e300, 1e300, 1e300]), (*STATE, "position_ecef_m", 0)),
    "speed_1e9": (_set((*STATE, "velocity_ecef_m_s"), [1e9, 0, 0]), (*STATE, "velocity_ecef_m_s")),
    "ephemeris_inside_earth": (
        _set(("images", 0, "ephemeris", 0, "position_ecef_m"), [1000.0, 0.0, 0.0]),
        ("images", 0, "ephemeris", 0, "position_ecef_m"),
    ),
    "point_1e308": (_set(("points", 0, "coordinates"), [1e308, 1e308, 1e308]), ("points", 0, "coordinates", 0)),
    "point_in_space": (_set(("points", 0, "coordinates"), [-51.0, -22.0, 1e7]), ("points", 0, "coordinates")),
    "point_latitude_1e7": (_set(("points", 0, "coordinates"), [1e7, 1e7, 0.0]), ("points", 0, "coordinates")),
    "on1_omega_string": (_model("ON1", {"omega_deg": "abc"}), ("images", 0, "model", "options", "omega_deg")),
    "on1_omega_list": (_model("ON1", {"omega_deg": [1]}), ("images", 0, "model", "options", "omega_deg")),
    "option_of_another_model": (_model("K2", {"omega_deg": 1.0}), ("images", 0, "model", "options", "omega_deg")),
    "unknown_option": (_model("K2", {"foo": 1}), ("images", 0, "model", "options", "foo")),
    "covariance_negative": (_weighted_iop(["df"], [[-1.0]]), ("cameras", 0, "iop_covariance")),
    "covariance_zero": (_weighted_iop(["df"], [[0.0]]), ("cameras", 0, "iop_covariance")),
    "covariance_not_positive_definite": (
        _weighted_iop(["df", "x0"], [[1e-4, 1.0], [1.0, 1e-4]]),
        ("cameras", 0, "iop_covariance"),
    ),
    "covariance_duplicate_names": (
        _weighted_iop(["df", "df"], [[1e-4, 0.0], [0.0, 1e-4]]),
        ("cameras", 0, "iop_covariance", "names"),
    ),
    "estimate_twice": (
        _set(("options", "self_calibration"), {"estimate": ["df", "df"]}),
        ("options", "self_calibration", "estimate"),
    ),
    "geoid_grid_missing": (
        _set(("crs",), "+proj=longlat +datum=WGS84 +geoidgrids=no_such_grid.tif +vunits=m +no_defs"),
        ("crs",),
    ),
    "focal_as_string": (_set(("cameras", 0, "focal_mm"), "481.8"), ("cameras", 0, "focal_mm")),
    "focal_5e-324": (_set(("cameras", 0, "focal_mm"), 5e-324), ("cameras", 0, "focal_mm")),
    "lines_as_float": (_set(("cameras", 0, "lines"), 16000.0), ("cameras", 0, "lines")),
    "lines_as_string": (_set(("cameras", 0, "lines"), "16000"), ("cameras", 0, "lines")),
    "sigma_as_bool": (_set(("observations", 0, "sigma_px"), True), ("observations", 0, "sigma_px")),
    "sigma_1e-9_px": (_set(("observations", 0, "sigma_px"), 1e-9), ("observations", 0, "sigma_px")),
    "covariance_flag_as_string": (_set(("options", "covariance"), "false"), ("options", "covariance")),
    "models_500_times": (_set(("options", "models"), ["K2"] * 500), ("options", "models")),
    "model_twice": (_set(("options", "models"), ["K2", "k2"]), ("options", "models", 1)),
    "model_alias_twice": (_set(("options", "models"), ["ON2", "MT12"]), ("options", "models", 1)),
}


def bad_job(case: str) -> dict[str, Any]:
    doc = triplet()
    CASES[case][0](doc)
    return doc
