"""Names of the interior-orientation parameters (docs/models.md section 8), shared by the job
schema (which refuses unknown names) and the numerical kernels (which lay the vector out).

A camera's IOP vector is the optical parameters then, per CCD chip, the chip parameters
(named ``<name>@<chip id>``); a camera has at most ``MAX_CHIPS`` chips.
"""

from __future__ import annotations

IOP_OPTICAL = ("x0", "y0", "df", "k1", "k2", "sy")
IOP_CHIP = ("a0", "b0", "a1", "b1", "delta")
MAX_CHIPS = 8


def camera_iop_names(chip_ids: list[str]) -> list[str]:
    """Every IOP name of a camera with these chip ids (a camera without chips has chip "1")."""
    names = list(IOP_OPTICAL)
    for cid in chip_ids or ["1"]:
        names += [f"{p}@{cid}" for p in IOP_CHIP]
    return names
