"""DEM heights as observations of the tie points (``job.dem``; docs/datum.md).

For each tie point (but those in ``dem.excluded``) the DEM's ellipsoidal height at the point's
current horizontal position is an observation of the point's height::

    v = h_dem(lon, lat) - h(point)        (metres; observed - model)

with the standard deviation of :func:`solver.geometry.dem.height_sigma` (the DEM's stated
accuracy, the local slope times the point's horizontal precision and the DEM's cell against
the image's ground sample distance). The point is the adjustment's LGS point (east, north, up
at the frame's origin); its geodetic longitude, latitude and height come from the frame, and
the derivatives of v along the LGS axes are those of the local east, north and up at the
point (the LGS axes differ from them by the Earth's curvature, 1.6 mrad over 10 km)::

    dv/dp = s_e e(p) + s_n n(p) - u(p)      (s_e, s_n: the DEM's slope, m/m)

The term of a point is linear in the point around the position it was sampled at (a constant
slope): its ``linear_form`` runs without Python on the compiled path, and ``refresh`` samples
the DEM again where the point has moved, until no whitened residual changes by more than
:data:`solver.observations.family.REFRESH_TOL` (the DEM is re-read as the point moves).

A tie point on a roof, a tree or water is not on the terrain a DTM gives (a DSM gives the
tops): the DEM heights take a robust loss (``dem.loss``, Huber by default) and data snooping
tests each (removal: the point's DEM height, not the point). The report section ``dem`` gives
the residuals, their statistics and the test of a common DEM bias
(:func:`solver.quality.datum.dem_bias_test`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.errors import Problem
from solver.geometry.dem import Dem, DemError, grid_from_job, height_sigma
from solver.geometry.geodesy import LocalFrame, ecef_to_geodetic, enu_rotation
from solver.observations.family import Count, FamilyDefaults, GroupSpec, Labelled, ReportContext

if TYPE_CHECKING:
    from solver.schema.job import Job
    from solver.state import AdjustmentState


def local_axes_in_lgs(frame: LocalFrame, xyz_lgs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lon, lat, h) (n, 3: degrees, degrees, metres) of LGS points and their local east,
    north, up unit vectors expressed in the LGS axes (n, 3, 3: rows e, n, u)."""
    xyz = np.atleast_2d(np.asarray(xyz_lgs, dtype=float))
    llh = ecef_to_geodetic(frame.to_ecef(xyz))
    axes = np.empty((len(xyz), 3, 3))
    r = frame.rotation_ecef_to_lgs
    for i, (lon, lat, _h) in enumerate(llh):
        axes[i] = enu_rotation(np.radians(lon), np.radians(lat)) @ r.T  # rows: local e, n, u in LGS components
    return llh, axes


@dataclass
class DemSample:
    """The DEM at points: ``h_dem`` (n,) ellipsoidal metres, ``slope`` (n, 2) m/m east and north,
    ``height`` (n,) the points' own ellipsoidal heights, ``gradient`` (n, 3) dv/dp along the LGS
    axes, all NaN where the DEM has no height."""

    h_dem: np.ndarray
    slope: np.ndarray
    height: np.ndarray
    gradient: np.ndarray

    @property
    def residual(self) -> np.ndarray:
        """v = h_dem - h (metres)."""
        return self.h_dem - self.height


def sample(frame: LocalFrame, dem: Dem, xyz_lgs: np.ndarray) -> DemSample:
    """The DEM under LGS points (module docstring)."""
    llh, axes = local_axes_in_lgs(frame, xyz_lgs)
    h_dem, slope = dem.sample(llh[:, 0], llh[:, 1])
    gradient = slope[:, :1] * axes[:, 0] + slope[:, 1:2] * axes[:, 1] - axes[:, 2]
    return DemSample(h_dem, slope, llh[:, 2], gradient)


def point_sigmas(sigma_dem_m: float, slope: np.ndarray, sigma_xy_m: np.ndarray, cell_m: float, gsd_m: np.ndarray) -> np.ndarray:
    """The DEM height's sigma at each point (:func:`solver.geometry.dem.height_sigma`)."""
    return height_sigma(sigma_dem_m, np.hypot(slope[:, 0], slope[:, 1]), sigma_xy_m, cell_m, gsd_m)


@dataclass
class DemTerm:
    """The DEM height of one point, linearised at ``xyz0`` (LGS): whitened residual
    ``w (v0 + g . (p - xyz0))`` with v0 = h_dem - h at xyz0, g = dv/dp there, w = 1/sigma."""

    point_index: int
    xyz0: np.ndarray
    v0: float
    g: np.ndarray
    w: float
    robust: tuple[str, float] | None = None  # (loss, scale in sigmas): the job's dem.loss

    n_residuals: int = 1

    def loss(self) -> tuple[str, float] | None:
        """The robust loss Ceres applies to this term (None: least squares)."""
        return self.robust

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = self.w * (self.v0 + self.g @ (np.asarray(params, dtype=float) - self.xyz0))
        return np.array([r]), (self.w * self.g)[None, :]

    def linear_form(self) -> tuple[np.ndarray, np.ndarray]:
        """A p - b with A = w g, b = w (g . xyz0 - v0)."""
        a = (self.w * self.g)[None, :]
        return a, np.array([self.w * (self.g @ self.xyz0 - self.v0)])


MIN_GSD_TIES = 3  # tie points an image needs for its ground sample distance (an affine fit)


def image_gsd_m(problem: "AdjustmentState") -> np.ndarray:
    """Each image's ground sample distance (metres per pixel) from its tie points: the affine
    fit of (line, column) to the points' LGS (east, north), 1 / sqrt(|det|) (NaN with fewer than
    :data:`MIN_GSD_TIES` points)."""
    obs = problem.obs
    xyz = np.array([p.xyz for p in problem.points]) if problem.points else np.zeros((0, 3))
    out = np.full(len(problem.images), np.nan)
    for img in problem.images:
        rows = np.flatnonzero(obs.img == img.index)
        if len(rows) < MIN_GSD_TIES:
            continue
        en = np.column_stack([xyz[obs.pt[rows], :2], np.ones(len(rows))])
        coef, *_ = np.linalg.lstsq(en, obs.oc[rows, :2], rcond=None)
        det = abs(float(np.linalg.det(coef[:2, :2])))
        if det > 0:
            out[img.index] = 1.0 / np.sqrt(det)
    return out


def point_precision(problem: "AdjustmentState", gsd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per point: the finest GSD of the images that see it and its horizontal precision from
    its measurements (sigma_px x GSD over the square root of its image count), metres."""
    obs = problem.obs
    n = len(problem.points)
    g = np.full(n, np.inf)
    inv_var = np.zeros(n)
    gi = gsd[obs.img]
    ok = np.isfinite(gi)
    np.minimum.at(g, obs.pt[ok], gi[ok])
    inv_var += np.bincount(obs.pt[ok], weights=1.0 / (obs.oc[ok, 2] * gi[ok]) ** 2, minlength=n)
    sigma_xy = np.where(inv_var > 0, 1.0 / np.sqrt(np.where(inv_var > 0, inv_var, 1.0)), np.nan)
    return np.where(np.isfinite(g), g, np.nan), sigma_xy


@dataclass
class DemState:
    """The job's DEM in an adjustment: the grid, the images' GSD and, per point, its term's
    current linearisation (refreshed as the point moves)."""

    dem: Dem
    sigma_dem_m: float
    gsd: np.ndarray  # per image
    terms: dict[int, DemTerm]  # point index -> term
    sigma: dict[int, float]  # point index -> the DEM height's sigma (m)
    outside: list[str]  # tie points outside the DEM or over no data


def _linearise(problem: "AdjustmentState", st: DemState, indices: list[int]) -> dict[int, DemTerm]:
    if not indices:
        return {}
    xyz = np.array([problem.points[i].xyz for i in indices])
    smp = sample(problem.frame, st.dem, xyz)
    _g, sigma_xy = point_precision(problem, st.gsd)
    out = {}
    for k, i in enumerate(indices):
        if not np.isfinite(smp.h_dem[k]):
            continue
        gsd = _g[i] if np.isfinite(_g[i]) else st.dem.cell_m
        sxy = sigma_xy[i] if np.isfinite(sigma_xy[i]) else gsd
        sigma = float(point_sigmas(st.sigma_dem_m, smp.slope[k : k + 1], np.array([sxy]), st.dem.cell_m, np.array([gsd]))[0])
        st.sigma[i] = sigma
        robust = (problem.job.dem.loss, float(problem.job.dem.loss_scale)) if problem.job.dem is not None else None
        out[i] = DemTerm(i, xyz[k].copy(), float(smp.residual[k]), smp.gradient[k].copy(), 1.0 / sigma, robust)
    return out


def _tie_indices(problem: "AdjustmentState") -> list[int]:
    dem = problem.job.dem
    excluded = set(dem.excluded) if dem is not None else set()
    return [p.index for p in problem.points if p.role == "tie" and p.estimated and p.id not in excluded]


class DemHeightsFamily(FamilyDefaults):
    """The family of the module docstring (``job.dem``; report section ``dem``)."""

    name = "dem"

    def check(self, job: "Job") -> tuple[list[Problem], Count]:
        if job.dem is None:
            return [], Count()
        problems: list[Problem] = []
        try:
            grid_from_job(job.dem.grid.model_dump())
        except DemError as exc:
            problems.append(Problem("bad_dem_grid", str(exc), ("dem", "grid")))
        ties = {p.id for p in job.points if p.role == "tie"}
        for k, pid in enumerate(job.dem.excluded):
            if pid not in ties:
                problems.append(Problem("unknown_point", f"dem.excluded names {pid!r}, which is not a tie point", ("dem", "excluded", k)))
        n = len(ties - set(job.dem.excluded))
        # heights of the terrain: with the slopes also some horizontal hold; the datum analysis
        # before the solve says which directions remain undetermined
        return problems, Count(n_observations=n, datum=frozenset({"control"}) if n else frozenset())

    def _state(self, problem: "AdjustmentState") -> DemState | None:
        job = problem.job
        if job.dem is None:
            return None
        st = getattr(problem, "dem", None)
        if st is None:
            dem = grid_from_job(job.dem.grid.model_dump())
            st = DemState(dem, float(job.dem.sigma_m), image_gsd_m(problem), {}, {}, [])
            st.terms = _linearise(problem, st, _tie_indices(problem))
            st.outside = [problem.points[i].id for i in _tie_indices(problem) if i not in st.terms]
            problem.dem = st
        return st

    def terms(self, problem: "AdjustmentState") -> list[Labelled]:
        st = self._state(problem)
        if st is None:
            return []
        return [Labelled(self, term, "point", i) for i, term in st.terms.items()]

    def refresh(self, problem: "AdjustmentState") -> float:
        """Sample the DEM again where the points are now; the largest change of a whitened
        residual at the current positions (old linearisation against the new one)."""
        st = self._state(problem)
        if st is None or not st.terms:
            return 0.0
        indices = list(st.terms)
        xyz = np.array([problem.points[i].xyz for i in indices])
        smp = sample(problem.frame, st.dem, xyz)
        change = 0.0
        for k, i in enumerate(indices):
            term = st.terms[i]
            if not np.isfinite(smp.h_dem[k]):
                continue  # left the DEM: keep its last linearisation
            old = term.evaluate(xyz[k])[0][0]
            term.xyz0, term.v0, term.g = xyz[k].copy(), float(smp.residual[k]), smp.gradient[k].copy()
            change = max(change, abs(term.w * term.v0 - old))
        return change

    def groups(self, problem: "AdjustmentState", labelled: Labelled) -> list[GroupSpec]:
        pid = problem.points[labelled.index].id
        sigma = 1.0 / labelled.term.w
        return [GroupSpec("dem_height", np.array([0]), {"point": pid}, np.array([sigma]), "m", ["h"], 1.0, ("dem_height", pid))]

    def report(self, problem: "AdjustmentState", ctx: ReportContext) -> dict[str, Any]:
        st = self._state(problem)
        if st is None:
            return {}
        return {"dem": dem_report(problem, st)}

    def without(self, job: "Job", removals: list[tuple]) -> tuple["Job", list[dict[str, Any]]]:
        """``job`` with the removed DEM heights in ``dem.excluded``; a tie point the same
        removals leave with fewer than two rays leaves the job (solver.quality.removal.remove),
        and so leaves ``dem.excluded`` (which names tie points only)."""
        gone = [r[1] for r in removals if r and r[0] == "dem_height"]
        if job.dem is None or not removals:
            return job, []
        dropped_obs = {r[1] for r in removals if r and r[0] == "observation"}
        rays: dict[str, int] = {}
        for k, o in enumerate(job.observations):
            if k not in dropped_obs:
                rays[o.point] = rays.get(o.point, 0) + 1
        staying = {p.id for p in job.points if p.role == "tie" and rays.get(p.id, 0) >= 2}
        excluded = [pid for pid in dict.fromkeys([*job.dem.excluded, *gone]) if pid in staying]
        if excluded == list(job.dem.excluded):
            return job, []
        return job.model_copy(update={"dem": job.dem.model_copy(update={"excluded": excluded})}), []

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        section = report.get("dem")
        if not section:
            return
        gone = {r.get("point") for r in removed if r.get("kind") == "dem_height"}
        for p in section.get("points", []):
            p["rejected"] = p["point"] in gone


def _excluded_indices(problem: "AdjustmentState") -> list[int]:
    dem = problem.job.dem
    excluded = set(dem.excluded) if dem is not None else set()
    return [p.index for p in problem.points if p.role == "tie" and p.estimated and p.id in excluded]


def dem_report(problem: "AdjustmentState", st: DemState) -> dict[str, Any]:
    """The report's ``dem`` section at the current parameters: per tie point the DEM height,
    the point's adjusted height, the residual v = h_dem - h and its sigma; their statistics
    (of the DEM heights used). The points in ``dem.excluded`` (data snooping's removals, or
    the job's own) follow with ``used`` false: their DEM height at their adjusted position,
    outside the adjustment and the statistics."""
    indices = list(st.terms)
    excluded = [i for i in _excluded_indices(problem) if i not in st.terms]
    if excluded:  # their sigma as if used (the formula at their current position)
        for i, term in _linearise(problem, st, excluded).items():
            st.sigma[i] = 1.0 / term.w
        excluded = [i for i in excluded if i in st.sigma]
    every = indices + excluded
    xyz = np.array([problem.points[i].xyz for i in every]) if every else np.zeros((0, 3))
    smp = sample(problem.frame, st.dem, xyz)
    sig = np.array([st.sigma[i] for i in every])
    rows = [{"point": problem.points[i].id, "dem_height_m": float(smp.h_dem[k]), "height_m": float(smp.height[k]),
             "residual_m": float(smp.residual[k]), "sigma_m": float(sig[k]), "slope": float(np.hypot(*smp.slope[k])),
             "used": k < len(indices)}
            for k, i in enumerate(every)]
    v = smp.residual[: len(indices)]
    sig = sig[: len(indices)]
    finite = np.isfinite(v)
    stats: dict[str, Any] = {"n": int(finite.sum())}
    if finite.any():
        vf, sf = v[finite], sig[finite]
        w = 1.0 / sf**2
        stats.update({"mean_m": float(vf.mean()), "weighted_mean_m": float((w * vf).sum() / w.sum()),
                      "std_m": float(vf.std(ddof=1)) if vf.size > 1 else None,
                      "rms_m": float(np.sqrt(np.mean(vf**2))), "median_m": float(np.median(vf)),
                      "rms_normalised": float(np.sqrt(np.mean((vf / sf) ** 2)))})
    return {"source": st.dem.source, "vertical": problem.job.dem.grid.vertical, "cell_m": st.dem.cell_m,
            "sigma_dem_m": st.sigma_dem_m, "image_gsd_m": [None if not np.isfinite(g) else float(g) for g in st.gsd],
            "statistics": stats, "points": rows, "outside": st.outside}


FAMILY = DemHeightsFamily()
