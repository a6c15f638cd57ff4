"""What makes an RPC export's check grid an independent check of its fit (solver/geometry/rpc.py
``FIT_GRID``, ``CHECK_GRID``), for the tests of every module that fits one: no check point is a
fit point. Check heights lie strictly between the fit layers (and inside their range), check
image positions are the cells' centres, none on a fit position. Moved onto the fit layers, the
check would repeat the fit's residuals there and miss what the polynomials do between them."""

from __future__ import annotations

import numpy as np

from solver.geometry.rpc import CHECK_GRID, FIT_GRID, GroundGrid


def spy_grids(monkeypatch, module) -> dict[str, GroundGrid]:  # noqa: ANN001
    """The fit and check grids ``module`` hands to its ``fit_record`` (filled when it is called)."""
    grids: dict[str, GroundGrid] = {}
    real = module.fit_record

    def spy(rpc, fit_g, check_g, height_range_m, **fields):  # noqa: ANN001, ANN003, ANN202
        grids.update(fit=fit_g, check=check_g)
        return real(rpc, fit_g, check_g, height_range_m, **fields)

    monkeypatch.setattr(module, "fit_record", spy)
    return grids


def assert_independent(fit: GroundGrid, check: GroundGrid) -> None:
    fit_h, check_h = np.unique(np.round(fit.h, 3)), np.unique(np.round(check.h, 3))
    spacing = float(np.min(np.diff(fit_h)))
    assert len(fit_h) == FIT_GRID[2] and len(check_h) == CHECK_GRID[2], (fit_h, check_h)
    gaps = np.abs(check_h[:, None] - fit_h[None, :]).min(axis=1)
    assert np.all(gaps > 0.25 * spacing), (check_h, fit_h)  # between the layers, not on them
    assert fit_h.min() < check_h.min() and check_h.max() < fit_h.max()
    fit_pos = {(round(a, 6), round(b, 6)) for a, b in zip(fit.line, fit.column)}
    assert not fit_pos & {(round(a, 6), round(b, 6)) for a, b in zip(check.line, check.column)}
