"""A smooth synthetic terrain: ellipsoidal height as a sum of plane waves.

``h(lon, lat) = mean + sum_k A_k sin(2 pi (e cos a_k + n sin a_k) / L_k + p_k)`` where (e, n)
are metres east/north of the centre on a local tangent approximation. Because
``sum A_k = (max - min) / 2`` the height never leaves [min, max] (default 350-550 m, the
Presidente Prudente area).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

_M_PER_DEG = 111_319.49  # metres per degree on the equator of WGS 84


@dataclass(frozen=True)
class Terrain:
    """Ellipsoidal height (m) over geodetic longitude/latitude (degrees)."""

    centre_lon_deg: float
    centre_lat_deg: float
    min_height_m: float = 350.0
    max_height_m: float = 550.0
    wavelengths_m: tuple[float, ...] = (27_000.0, 13_000.0, 6_100.0, 2_900.0)
    weights: tuple[float, ...] = (0.45, 0.30, 0.15, 0.10)
    directions_rad: tuple[float, ...] = (0.3, 1.9, 4.0, 5.2)
    phases_rad: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0)

    @classmethod
    def random(cls, rng: np.random.Generator, lon_deg: float, lat_deg: float, **kw: float) -> "Terrain":
        return cls(
            lon_deg,
            lat_deg,
            directions_rad=tuple(float(x) for x in rng.uniform(0, 2 * np.pi, 4)),
            phases_rad=tuple(float(x) for x in rng.uniform(0, 2 * np.pi, 4)),
            **kw,
        )

    def height(self, lon_deg: np.ndarray, lat_deg: np.ndarray) -> np.ndarray:
        e = (np.asarray(lon_deg) - self.centre_lon_deg) * _M_PER_DEG * np.cos(np.radians(self.centre_lat_deg))
        n = (np.asarray(lat_deg) - self.centre_lat_deg) * _M_PER_DEG
        mean = 0.5 * (self.min_height_m + self.max_height_m)
        amp = 0.5 * (self.max_height_m - self.min_height_m) / sum(self.weights)
        h = np.full(np.shape(e), mean, dtype=float)
        for lam, w, a, p in zip(self.wavelengths_m, self.weights, self.directions_rad, self.phases_rad, strict=True):
            h = h + amp * w * np.sin(2 * np.pi * (e * np.cos(a) + n * np.sin(a)) / lam + p)
        return h

    def to_dict(self) -> dict:
        return asdict(self)
