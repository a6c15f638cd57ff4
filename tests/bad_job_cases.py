"""Malformed jobs (mutations of examples/prism-triplet.json) and where each must be refused.

Shared by tests/test_bad_input.py (through solver.api) and tests/service/routes/test_service_bad_input.py
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
def _rpc(**changes: Any) -> dict[str, Any]:
    """A well-formed RPC00B near the example's ground (line = -lat, sample = lon, normalised);
    validation does not need it to be the image's true geometry."""
    unit = [0.0] * 20
    den = [1.0] + [0.0] * 19
    rpc = {
        "line_off": 8000.0, "samp_off": 2000.0, "lat_off": -22.0, "long_off": -51.2, "height_off": 450.0,
        "line_scale": 8000.0, "samp_scale": 2000.0, "lat_scale": 0.2, "long_scale": 0.2, "height_scale": 500.0,
        "line_num_coeff": [0.0, 0.0, -1.0] + unit[3:], "line_den_coeff": list(den),
        "samp_num_coeff": [0.0, 1.0] + unit[2:], "samp_den_coeff": list(den),
    }
    rpc.update(changes)
    return rpc


def _rpc_image(extra: dict[str, Any] | None = None, keep: tuple[str, ...] = (), **changes: Any) -> Callable[[dict[str, Any]], None]:
    """Image 0 becomes an RPC-DRIFT image (RPC from :func:`_rpc`), keeping the fields ``keep``."""

    def mutate(doc: dict[str, Any]) -> None:
        im = doc["images"][0]
        doc["images"][0] = {"id": im["id"], "model": {"name": "RPC-DRIFT"}, "rpc": _rpc(**changes),
                            **{k: im[k] for k in keep}, **(extra or {})}

    return mutate


def _add_rpc(doc: dict[str, Any]) -> None:
    doc["images"][0]["rpc"] = _rpc()


CASES: dict[str, tuple[Callable[[dict[str, Any]], None], tuple]] = {
    "rpc_model_without_rpc": (_model("RPC-SHIFT", {}), ("images", 0, "rpc")),
    "rpc_with_rigorous_model": (_add_rpc, ("images", 0, "rpc")),
    "rpc_zero_scale": (_rpc_image(lat_scale=0.0), ("images", 0, "rpc", "lat_scale")),
    "rpc_zero_denominator": (_rpc_image(samp_den_coeff=[0.0] * 20), ("images", 0, "rpc", "samp_den_coeff", 0)),
    "rpc_19_coefficients": (_rpc_image(line_num_coeff=[0.0] * 19), ("images", 0, "rpc", "line_num_coeff")),
    "rpc_bad_pixel_convention": (_rpc_image(pixel_convention="corner"), ("images", 0, "rpc", "pixel_convention")),
    "rpc_image_with_camera": (_rpc_image(keep=("camera",)), ("images", 0, "camera")),
    "rpc_image_with_approx_state": (_rpc_image(keep=("approx_state",)), ("images", 0, "approx_state")),
    "rpc_image_with_ephemeris": (_rpc_image(keep=("ephemeris", "first_line_time_s")), ("images", 0, "ephemeris")),
    "rpc_image_with_attitude": (_rpc_image(keep=("attitude",)), ("images", 0, "attitude")),
    "rpc_unknown_initial": (_rpc_image({"initial": {"X0": 1.0}}), ("images", 0, "initial", "X0")),
    "rpc_prior_not_estimated": (
        _rpc_image({"bias_prior": {"a_column": {"value": 0.0, "sigma": 1e-5}}}),
        ("images", 0, "bias_prior", "a_column"),
    ),
    "rpc_prior_zero_sigma": (
        _rpc_image({"bias_prior": {"a0": {"value": 0.0, "sigma": 0.0}}}),
        ("images", 0, "bias_prior", "a0", "sigma"),
    ),
    "rpc_model_options": (_rpc_image({"model": {"name": "RPC-SHIFT", "options": {"orders": {"X": 1}}}}), ("images", 0, "model", "options")),
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
