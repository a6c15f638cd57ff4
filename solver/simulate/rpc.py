"""Simulated RPC images: the RPC00B fitted to the simulator's true geometry plus a known bias.

For an image chosen as an RPC image (``pba simulate ... --rpc-model RPC-DRIFT --rpc-bias ...``):

1. The delivered image. A single-chip camera's image is the raw image (its true geometry, IOP
   errors included). A multi-chip camera's raw image has no smooth RPC (the chips' offsets make
   it jump at the seams), so the delivered image is the **chip-aligned ideal image** of the GIS
   outputs (:mod:`solver.gis.resample`, same definition, built here from the simulator's own
   camera since the simulator imports nothing of the adjustment): one straight line of
   ``columns`` pixels of the camera's pixel size centred on the principal point, at the chips'
   mean along-track position ``dx``, the nominal focal length, no interior-orientation errors;
   same platform, same line timing. The image's simulated measurements are made in it.
2. The RPC. A grid of ``FIT_GRID`` image positions (pixel centres, corners included) times
   heights spanning the terrain's range +- ``HEIGHT_MARGIN_M`` is cast to the ground through the
   exact projection (:mod:`solver.simulate.projection`); each ground point's target is the true
   image position minus the bias at it (:meth:`solver.geometry.rpc.RpcBias.to_rpc`), so that
   ``true observed = RPC + bias`` as the RPC models define it (exact for the affine bias, which is
   explicit in the observed coordinates). The RPC00B is fitted by :func:`solver.geometry.rpc.fit_rpc`
   (:func:`solver.geometry.rpc.fit_rpc_best`: the better of two Tikhonov weights on the check
   grid) and assessed on an independent check grid (cells' centres, heights between the fit layers):
   ``check_residuals`` (pixels) in the truth file.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic
from solver.geometry.rpc import BIAS_MODELS, BIAS_NAMES, CHECK_GRID, FIT_GRID, RPC, GroundGrid, RpcBias, fit_record, fit_rpc_best, heights_of
from solver.simulate.camera import CameraSpec, ChipSpec
from solver.simulate.iop import NO_IOP
from solver.simulate.projection import ImageGeometry

HEIGHT_MARGIN_M = 100.0
IDEAL_CHIP_ID = "ideal"


class RpcSettingsError(ValueError):
    """RPC settings that do not fit the scene (e.g. an image number it does not have)."""


@dataclass(frozen=True)
class RpcSettings:
    """Which images are RPC images, their model and the bias their delivered RPC carries."""

    model: str = "RPC-DRIFT"
    bias: dict[str, float] | None = None  # {name: value} of solver.geometry.rpc.BIAS_NAMES
    images: tuple[int, ...] | None = None  # 1-based image numbers; None: every image

    def __post_init__(self) -> None:
        if self.model not in BIAS_MODELS:
            raise ValueError(f"unknown RPC model {self.model!r} (one of {', '.join(BIAS_MODELS)})")
        RpcBias.from_parameters(self.bias or {})

    @property
    def rpc_bias(self) -> RpcBias:
        return RpcBias.from_parameters(self.bias or {})

    def selects(self, index: int) -> bool:
        """Is image ``index`` (0-based) an RPC image?"""
        return self.images is None or index + 1 in self.images


def parse_bias(text: str) -> dict[str, float]:
    """``"a0=20,b0=-12,a_line=1e-4"`` -> ``{"a0": 20.0, "b0": -12.0, "a_line": 1e-4}``."""
    out: dict[str, float] = {}
    for item in filter(None, (x.strip() for x in text.split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in BIAS_NAMES:
            raise ValueError(f"bad RPC bias item {item!r}: NAME=VALUE with NAME one of {', '.join(BIAS_NAMES)}")
        out[name] = float(value)
    return out


def ideal_camera(cam: CameraSpec) -> CameraSpec:
    """The chip-aligned ideal camera of a multi-chip camera (module docstring, item 1)."""
    dx = float(np.mean([c.dx_mm for c in cam.chips]))
    return replace(cam, chips=(ChipSpec(IDEAL_CHIP_ID, 0, cam.columns, dx, 0.0),), iop=NO_IOP)


def delivered_geometry(im: ImageGeometry) -> ImageGeometry:
    """The image an RPC describes: the raw image of a single-chip camera, the ideal image of a
    multi-chip one (same id, platform and timing)."""
    if len(im.camera.chips) == 1:
        return im
    return replace(im, camera=ideal_camera(im.camera))


def _grid(im: ImageGeometry, bias: RpcBias, heights: np.ndarray, n: tuple[int, int], cell_centres: bool) -> GroundGrid:
    """Ground points of an image grid at each height; (line, column) = what the RPC must give."""
    cam = im.camera

    def axis(hi: float, k: int) -> np.ndarray:
        if cell_centres:
            return hi / k * (np.arange(k) + 0.5)
        return np.linspace(0.0, hi, k)

    ll, cc = np.meshgrid(axis(cam.lines - 1.0, n[0]), axis(cam.columns - 1.0, n[1]), indexing="ij")
    ll, cc = ll.ravel(), cc.ravel()
    llh = np.vstack([ecef_to_geodetic(im.image_to_ground(ll, cc, height_m=float(h))) for h in heights])
    m = len(heights)
    rl, rc = bias.to_rpc(np.tile(ll, m), np.tile(cc, m))
    return GroundGrid(rl, rc, llh[:, 0], llh[:, 1], llh[:, 2])


def fit_image_rpc(im: ImageGeometry, bias: RpcBias, height_range_m: tuple[float, float]) -> RPC:
    """The RPC of a delivered image carrying ``bias``, with fit and check residuals (pixels) in ``fit``."""
    hr = (height_range_m[0] - HEIGHT_MARGIN_M, height_range_m[1] + HEIGHT_MARGIN_M)
    fit_g = _grid(im, bias, heights_of(hr, FIT_GRID[2]), FIT_GRID[:2], False)
    check_g = _grid(im, bias, heights_of(hr, CHECK_GRID[2], True), CHECK_GRID[:2], True)
    rpc = fit_rpc_best(fit_g, check_g)
    rpc.fit = fit_record(rpc, fit_g, check_g, hr)
    return rpc


def rpc_truth(im: ImageGeometry, model: str, bias: RpcBias, rpc: RPC) -> dict[str, Any]:
    """The truth file's record of one RPC image."""
    return {
        "image": im.id,
        "model": model,
        "delivered_image": "raw" if im.camera.chips[0].id != IDEAL_CHIP_ID else "ideal",
        "bias": bias.as_dict(),
        "bias_equations": "line_obs = RPC_line + a0 + a_line line_obs + a_column column_obs; "
        "column_obs = RPC_column + b0 + b_line line_obs + b_column column_obs (pixel centres)",
        **rpc.fit,
    }
