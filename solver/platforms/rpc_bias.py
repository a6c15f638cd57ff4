"""RPC bias models (issue 17): an image whose sensor model is its RPC00B plus an image-space bias.

Grodecki & Dial (2003), "Block adjustment of high-resolution satellite images described by
rational polynomials", PE&RS 69(1): the bias is an affine function of the **observed** image
coordinates (our pixel convention: the centre of the top-left pixel is line 0, column 0)::

    line_obs   = RPC_line(lat, lon, h)   + a0 + a_line * line_obs + a_column * column_obs
    column_obs = RPC_column(lat, lon, h) + b0 + b_line * line_obs + b_column * column_obs

a0, b0 in pixels; a_line, a_column, b_line, b_column in pixels per pixel. The parameters a model
does not estimate are 0. The kernel is :func:`solver.kernels.rpc.rpc_project`.
"""

from __future__ import annotations

from solver.geometry.rpc import BIAS_MODELS, BIAS_NAMES
from solver.platforms.kinds import RPC_BIAS
from solver.platforms.registry import HELD, PlatformModel, register

_EQ = (
    "line_obs = RPC_line(lat,lon,h) + a0 + a_line line_obs + a_column column_obs; "
    "column_obs = RPC_column(lat,lon,h) + b0 + b_line line_obs + b_column column_obs"
)
_TITLES = {
    "RPC-SHIFT": "RPC with a bias shift: line and column offsets a0, b0",
    "RPC-DRIFT": "RPC with shift and drift: offsets plus a change with the line number (a_line, b_line)",
    "RPC-AFFINE": "RPC with the full image-space affine bias (six parameters)",
}
_ESTIMATED = {"RPC-SHIFT": "a0, b0", "RPC-DRIFT": "a0, a_line, b0, b_line", "RPC-AFFINE": "all six"}


def _bias(name: str) -> tuple[tuple[str, str, int], ...]:
    return tuple((n, "px" if n in ("a0", "b0") else "px/px", BIAS_NAMES.index(n)) for n in BIAS_MODELS[name])


for _name in ("RPC-SHIFT", "RPC-DRIFT", "RPC-AFFINE"):
    register(
        PlatformModel(
            name=_name,
            title=_TITLES[_name],
            kind=RPC_BIAS,
            frame="image (RPC00B of the image; WGS 84 geodetic ground)",
            orders=(HELD,) * 6,
            reference="Grodecki & Dial 2003 (PE&RS 69(1) 59-68), eqs 1-4",
            equations=f"{_EQ}; estimated: {_ESTIMATED[_name]}, the others 0",
            bias=_bias(_name),
        )
    )
