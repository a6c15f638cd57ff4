"""A simulated pass: orbit, images in groups (triplets or single scenes), points, noise, and the
two documents it produces: the job (:mod:`solver.schema.job` schema) and the truth file.

Procedure (all randomness from one ``numpy.random.Generator`` seeded by ``settings.seed``):

1. integrate the orbit over the pass; draw the attitude drift and the terrain;
2. for each group g (a scene area along the track), find the ground centre seen at nadir at
   ``t_g = g * lines * line_time`` and time every camera of the group so its centre line
   sees it;
3. draw candidate points uniformly in the group's reference image (the least tilted one),
   intersect their rays with the terrain, keep those seen by every image of the group away
   from chip seams; control points (gcp, then check) are picked by farthest-point sampling,
   so that ``--gcps 14 --checks 9`` and ``--gcps 9 --checks 14`` share the same 23 points;
   tie points are drawn at random among the rest;
4. project exactly (with the cameras' true interior orientation, ``settings.iop_errors``: the
   job gets the nominal cameras, the truth file the IOP), add Gaussian noise (image: ``noise_px`` on line and column; survey:
   ``gcp_sigma_m`` along east, north, up), drop observations that leave the image.

Times in the documents are ``epoch_s + t_s`` (seconds of the UTC day).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from solver.geometry.geodesy import LocalFrame, ecef_to_geodetic, enu_rotation, from_ecef
from solver.simulate.attitude import AttitudeModel, Platform, model_attitude_angles, opk_from_matrix
from solver.simulate.camera import CameraSpec
from solver.simulate.iop import resolve_iop
from solver.simulate.orbit import EarthModel, Orbit, circular_state_over, sun_synchronous_semi_major_axis
from solver.simulate.projection import ImageGeometry
from solver.simulate.rpc import RpcSettings, RpcSettingsError, delivered_geometry, fit_image_rpc, rpc_truth
from solver.simulate.terrain import Terrain

TRUTH_SCHEMA = "pba-simulation-truth/1"
SEAM_CLEARANCE_PX = 2.0


@dataclass
class SceneSettings:
    """Everything that defines a simulation (recorded in the truth file)."""

    preset: str
    seed: int = 1
    name: str = "simulated"
    model: str = "K2"
    noise_px: float = 0.5
    gcp_sigma_m: float = 0.2
    lon_deg: float = -51.39  # Presidente Prudente, Brazil
    lat_deg: float = -22.12
    inclination_deg: float = 98.16  # ALOS
    descending: bool = True
    epoch_s: float = 50112.0  # 13:55:12 UTC, nominal date 2008-11-20 (seed 000)
    crs: str = "EPSG:4326"
    approx_position_sigma_m: float = 10.0
    approx_velocity_sigma_m_s: float = 0.03
    ephemeris_step_s: float = 60.0
    ephemeris_margin_s: float = 180.0
    ephemeris_position_sigma_m: float = 1.0
    ephemeris_velocity_sigma_m_s: float = 0.001
    # measured attitude written with each image (images[].attitude): roll, pitch, yaw relative
    # to the orbital frame in the models' convention, every attitude_step_s on the pass's epoch
    # grid within the image's lines, with this noise (star-tracker class, ~7")
    attitude_step_s: float = 1.0
    attitude_sigma_deg: float = 0.002
    attitude_bias_rad: float = 2e-4
    attitude_rate_rad_s: tuple[float, float, float] = (1e-6, 1e-6, 1e-5)
    attitude_accel_rad_s2: float = 1e-8
    jitter_rad: float = 0.0
    jitter_hz: float = 0.5
    terrain_min_m: float = 350.0
    terrain_max_m: float = 550.0
    truth_step_lines: int = 100
    point_margin: float = 0.03  # fraction of the reference image kept free at its borders
    # interior-orientation errors of the simulated cameras (not written in the job): "none",
    # "default" (solver.simulate.iop.default_iop) or {camera id: {iop name: value}}
    iop_errors: Any = "none"
    # solver options written into the job (e.g. {"ephemeris": {...}, "attitude": {...}} to weight
    # the simulated state vectors and attitude samples); none by default
    job_options: dict[str, Any] = field(default_factory=dict)
    # RPC images (solver.simulate.rpc): which images, their model and the bias of their RPC;
    # None: every image has its camera and rigorous model
    rpc: RpcSettings | None = None


@dataclass
class SimPoint:
    id: str
    role: str
    group: int
    ecef_m: np.ndarray


@dataclass
class SimObservation:
    image: int
    point: int
    line: float  # noise-free
    column: float
    chip: int


@dataclass
class Group:
    """Images that see the same area (a triplet, or one scene) and its point counts."""

    cameras: list[CameraSpec]
    n_gcp: int
    n_check: int
    n_tie: int
    images: list[int] = field(default_factory=list)


class Scene:
    """A simulated pass. Build with :meth:`simulate`, then write :meth:`job` and :meth:`truth`."""

    def __init__(self, settings: SceneSettings, groups: list[Group], earth: EarthModel | None = None) -> None:
        self.settings = settings
        self.groups = [
            replace(
                g,
                cameras=[
                    replace(c, iop=resolve_iop(settings.iop_errors, c.id, c.focal_mm, [ch.id for ch in c.chips]))
                    for c in g.cameras
                ],
                images=[],
            )
            for g in groups
        ]
        self.earth = earth or EarthModel()
        self.rng = np.random.default_rng(settings.seed)
        self.images: list[ImageGeometry] = []
        self.points: list[SimPoint] = []
        self.observations: list[SimObservation] = []

    # -- 1. orbit, attitude, terrain ------------------------------------------------------
    def _setup_platform(self) -> None:
        s = self.settings
        ref_cam = self.groups[0].cameras[0]
        strip_s = len(self.groups) * ref_cam.lines * ref_cam.line_time_s
        margin = 120.0 + s.ephemeris_margin_s + s.ephemeris_step_s
        self.semi_major_axis_m = sun_synchronous_semi_major_axis(self.earth, s.inclination_deg)
        state0 = circular_state_over(self.earth, s.lon_deg, s.lat_deg, self.semi_major_axis_m, s.inclination_deg, s.descending)
        self.orbit = Orbit(self.earth, state0, -margin, strip_s + margin)
        att = AttitudeModel.random(
            self.rng, s.attitude_bias_rad, s.attitude_rate_rad_s, s.attitude_accel_rad_s2, s.jitter_rad, s.jitter_hz
        )
        self.platform = Platform(self.orbit, att)
        self.terrain = Terrain.random(self.rng, s.lon_deg, s.lat_deg, min_height_m=s.terrain_min_m, max_height_m=s.terrain_max_m)

    # -- 2. image timing --------------------------------------------------------------------
    def _place_images(self) -> None:
        for g, group in enumerate(self.groups):
            ref = group.cameras[0]
            t_g = g * ref.lines * ref.line_time_s
            aux = ImageGeometry("aux", CameraSpec("aux", ref.focal_mm, ref.pixel_mm, ref.line_time_s, 1, ref.columns, ref.chips, 0.0), self.platform, t_g)
            centre = aux.image_to_ground(np.array([0.0]), np.array([(ref.columns - 1) / 2.0]), terrain=self.terrain)
            r, v = self.orbit.state(t_g)
            height = np.linalg.norm(r) - np.linalg.norm(centre)
            for cam in group.cameras:
                guess = t_g - np.tan(np.radians(cam.mounting_pitch_deg)) * height / (np.linalg.norm(v) * 0.88)
                probe = ImageGeometry("probe", cam, self.platform, 0.0)
                t_c = probe.solve_time(centre, 0.0, np.array([guess]))[0]
                first = t_c - (cam.lines - 1) / 2.0 * cam.line_time_s
                group.images.append(len(self.images))
                suffix = "" if len(self.groups) == 1 else f"-{g + 1:02d}"
                self.images.append(ImageGeometry(f"{cam.id}{suffix}", cam, self.platform, float(first)))
        rpc = self.settings.rpc
        if rpc is not None and rpc.images is not None and not all(1 <= n <= len(self.images) for n in rpc.images):
            raise RpcSettingsError(f"--rpc-images {','.join(map(str, rpc.images))}: the scene has images 1..{len(self.images)}")
        if self.settings.rpc is not None:  # an RPC image is measured in the image its RPC describes
            self.images = [delivered_geometry(im) if self.settings.rpc.selects(k) else im for k, im in enumerate(self.images)]

    # -- 3. points ----------------------------------------------------------------------------
    def _candidates(self, group: Group, n: int) -> tuple[np.ndarray, list, np.ndarray, np.ndarray]:
        """Candidate ground points (n, 3), their projections into each image of the group, a mask
        of those seen by every image clear of chip seams, and their normalised (line, column)
        in the reference image (for spreading control points)."""
        imgs = [self.images[i] for i in group.images]
        ref = min(imgs, key=lambda im: abs(im.camera.mounting_pitch_deg))
        m = self.settings.point_margin
        lines = self.rng.uniform(m, 1 - m, n) * (ref.camera.lines - 1)
        cols = self.rng.uniform(m, 1 - m, n) * (ref.camera.columns - 1)
        pts = ref.image_to_ground(lines, cols, terrain=self.terrain)
        ok = np.ones(n, dtype=bool)
        projs = []
        for im in imgs:
            pr = im.ground_to_image(pts)
            seams = im.camera.seams()
            clear = np.all(np.abs(pr.column[:, None] - seams[None, :]) > SEAM_CLEARANCE_PX, axis=1) if len(seams) else True
            ok &= pr.inside & clear
            projs.append(pr)
        return pts, projs, ok, np.column_stack([lines / ref.camera.lines, cols / ref.camera.columns])

    @staticmethod
    def _farthest_point_order(xy: np.ndarray, k: int) -> list[int]:
        """Indices of k well-spread points: start at the one farthest from the centroid."""
        chosen = [int(np.argmax(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))]
        dist = np.linalg.norm(xy - xy[chosen[0]], axis=1)
        for _ in range(k - 1):
            j = int(np.argmax(dist))
            chosen.append(j)
            dist = np.minimum(dist, np.linalg.norm(xy - xy[j], axis=1))
        return chosen

    def _select_points(self) -> None:
        n_ctrl_total = sum(g.n_gcp + g.n_check for g in self.groups)
        width = max(2, len(str(n_ctrl_total)))
        n_tie_total = sum(g.n_tie for g in self.groups)
        tie_width = max(4, len(str(n_tie_total)))
        k_ctrl = k_tie = 0
        for gi, group in enumerate(self.groups):
            n_ctrl = group.n_gcp + group.n_check
            need = n_ctrl + group.n_tie
            n_cand = max(int(1.3 * need) + 200, 40 * n_ctrl)
            pts, projs, ok, xy = self._candidates(group, n_cand)
            valid = np.flatnonzero(ok)
            if len(valid) < need:
                raise RuntimeError(f"group {gi}: only {len(valid)} usable candidate points for {need}")
            ctrl = valid[self._farthest_point_order(xy[valid], n_ctrl)] if n_ctrl else np.array([], dtype=int)
            rest = np.setdiff1d(valid, ctrl)
            ties = self.rng.choice(rest, size=group.n_tie, replace=False) if group.n_tie else np.array([], dtype=int)
            for j, idx in enumerate(list(ctrl) + list(ties)):
                if j < n_ctrl:
                    k_ctrl += 1
                    role = "gcp" if j < group.n_gcp else "check"
                    pid = f"P{k_ctrl:0{width}d}"
                else:
                    k_tie += 1
                    role, pid = "tie", f"T{k_tie:0{tie_width}d}"
                p_index = len(self.points)
                self.points.append(SimPoint(pid, role, gi, pts[idx]))
                for im_index, pr in zip(group.images, projs, strict=True):
                    self.observations.append(
                        SimObservation(im_index, p_index, float(pr.line[idx]), float(pr.column[idx]), int(pr.chip[idx]))
                    )

    def simulate(self) -> "Scene":
        self._setup_platform()
        self._place_images()
        self._select_points()
        self._draw_noise()
        self._fit_rpcs()
        return self

    # -- RPC images ------------------------------------------------------------------------------
    def _fit_rpcs(self) -> None:
        """The delivered RPC of every RPC image: fitted to the true geometry plus the known bias."""
        s = self.settings
        self.rpcs = {}
        if s.rpc is None:
            return
        bias = s.rpc.rpc_bias
        for k, im in enumerate(self.images):
            if s.rpc.selects(k):
                self.rpcs[k] = fit_image_rpc(im, bias, (s.terrain_min_m, s.terrain_max_m))

    # -- 4. noise ------------------------------------------------------------------------------
    def _draw_noise(self) -> None:
        s = self.settings
        n_obs = len(self.observations)
        self.obs_noise_px = self.rng.normal(0.0, s.noise_px, (n_obs, 2)) if s.noise_px > 0 else np.zeros((n_obs, 2))
        ecef = np.array([p.ecef_m for p in self.points])
        llh = ecef_to_geodetic(ecef)
        enu_noise = self.rng.normal(0.0, s.gcp_sigma_m, (len(self.points), 3)) if s.gcp_sigma_m > 0 else np.zeros((len(self.points), 3))
        measured = ecef.copy()
        for i, p in enumerate(self.points):
            if p.role != "tie":
                rot = enu_rotation(np.radians(llh[i, 0]), np.radians(llh[i, 1]))
                measured[i] = ecef[i] + rot.T @ enu_noise[i]
        self.survey_noise_enu_m = enu_noise
        self.measured_ecef_m = measured
        # ephemeris noise: one realisation per epoch of the pass, shared by all images
        t_lo = min(im.first_line_time_s for im in self.images) - s.ephemeris_margin_s
        t_hi = max(im.time_of_line(im.camera.lines - 1) for im in self.images) + s.ephemeris_margin_s
        k0 = np.ceil((s.epoch_s + t_lo) / s.ephemeris_step_s)
        k1 = np.floor((s.epoch_s + t_hi) / s.ephemeris_step_s)
        self.ephemeris_t = np.arange(k0, k1 + 1) * s.ephemeris_step_s - s.epoch_s
        r, v = self.orbit.state(self.ephemeris_t)
        self.ephemeris_r = r + self.rng.normal(0.0, s.ephemeris_position_sigma_m, r.shape)
        self.ephemeris_v = v + self.rng.normal(0.0, s.ephemeris_velocity_sigma_m_s, v.shape)
        r0, v0, _ = self._line0_states()
        self.approx_r = r0 + self.rng.normal(0.0, s.approx_position_sigma_m, r0.shape)
        self.approx_v = v0 + self.rng.normal(0.0, s.approx_velocity_sigma_m_s, v0.shape)
        # attitude samples: their own generator, so that adding them left every other draw as it was
        t_lo = min(im.first_line_time_s for im in self.images)
        t_hi = max(im.time_of_line(im.camera.lines - 1) for im in self.images)
        k0 = np.ceil((s.epoch_s + t_lo) / s.attitude_step_s)
        k1 = np.floor((s.epoch_s + t_hi) / s.attitude_step_s)
        self.attitude_t = np.arange(k0, k1 + 1) * s.attitude_step_s - s.epoch_s
        true_deg = np.degrees(model_attitude_angles(self.platform.attitude.angles(self.attitude_t)))
        att_rng = np.random.default_rng([s.seed, 1])
        self.attitude_deg = true_deg + att_rng.normal(0.0, s.attitude_sigma_deg, true_deg.shape)

    def _line0_states(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.array([im.first_line_time_s for im in self.images])
        r, v = self.orbit.state(t)
        return r, v, t

    # -- documents -------------------------------------------------------------------------------
    def noisy_observations(self) -> list[tuple[SimObservation, float, float]]:
        """Observations with noise added, those outside their image dropped."""
        out = []
        for o, (dl, dc) in zip(self.observations, self.obs_noise_px, strict=True):
            cam = self.images[o.image].camera
            line, col = o.line + dl, o.column + dc
            if -0.5 <= line <= cam.lines - 0.5 and -0.5 <= col <= cam.columns - 0.5:
                out.append((o, line, col))
        return out

    def written_coordinates(self) -> np.ndarray:
        """gcp/check coordinates as written in the job (in ``settings.crs``), ties NaN."""
        out = from_ecef(self.measured_ecef_m, self.settings.crs)
        return out

    def job(self) -> dict[str, Any]:
        s = self.settings
        cams = {}
        for k, im in enumerate(self.images):
            if k not in self.rpcs:
                cams.setdefault(im.camera.id, im.camera.to_job())
        coords = self.written_coordinates()
        points = []
        for i, p in enumerate(self.points):
            d: dict[str, Any] = {"id": p.id, "role": p.role}
            if p.role != "tie":
                d["coordinates"] = [float(x) for x in coords[i]]
                if p.role == "gcp":
                    d["sigma_m"] = [s.gcp_sigma_m] * 3 if s.gcp_sigma_m > 0 else None
                    if d["sigma_m"] is None:
                        del d["sigma_m"]
            points.append(d)
        images = []
        for k, im in enumerate(self.images):
            if k in self.rpcs:  # an RPC image: no physical description
                images.append({"id": im.id, "rpc": self.rpcs[k].to_job(), "model": {"name": s.rpc.model}})
                continue
            t_first, t_last = im.first_line_time_s, im.time_of_line(im.camera.lines - 1)
            sel = (self.ephemeris_t >= t_first - s.ephemeris_margin_s) & (self.ephemeris_t <= t_last + s.ephemeris_margin_s)
            images.append(
                {
                    "id": im.id,
                    "camera": im.camera.id,
                    "model": {"name": s.model},
                    "first_line_time_s": s.epoch_s + im.first_line_time_s,
                    "approx_state": {
                        "position_ecef_m": [float(x) for x in self.approx_r[k]],
                        "velocity_ecef_m_s": [float(x) for x in self.approx_v[k]],
                    },
                    "ephemeris": [
                        {
                            "time_s": float(s.epoch_s + t),
                            "position_ecef_m": [float(x) for x in r],
                            "velocity_ecef_m_s": [float(x) for x in v],
                        }
                        for t, r, v in zip(self.ephemeris_t[sel], self.ephemeris_r[sel], self.ephemeris_v[sel], strict=True)
                    ],
                    "attitude": [
                        {"time_s": float(s.epoch_s + t), "roll_deg": float(a[0]), "pitch_deg": float(a[1]), "yaw_deg": float(a[2])}
                        for t, a in zip(self.attitude_t, self.attitude_deg, strict=True)
                        if t_first <= t <= t_last
                    ],
                }
            )
        observations = [
            {"image": self.images[o.image].id, "point": self.points[o.point].id, "line": float(line), "column": float(col), "sigma_px": max(s.noise_px, 1e-3)}
            for o, line, col in self.noisy_observations()
        ]
        job = {
            "schema_version": "1.0",
            "name": s.name,
            "crs": s.crs,
            "cameras": list(cams.values()),
            "images": images,
            "points": points,
            "observations": observations,
        }
        if s.job_options:
            job["options"] = json.loads(json.dumps(s.job_options))
        return job

    def true_cameras(self) -> dict[str, Any]:
        """Per camera id: the true interior orientation (every parameter of docs/models.md
        section 8 by name, zeros included) and the true focal length; the job has the nominal
        camera."""
        out: dict[str, Any] = {}
        for im in self.images:
            cam = im.camera
            out.setdefault(
                cam.id,
                {
                    "nominal_focal_mm": cam.focal_mm,
                    "true_focal_mm": cam.true_focal_mm,
                    "iop": cam.iop.full([c.id for c in cam.chips]),
                },
            )
        return out

    def lgs(self) -> LocalFrame:
        """The solver's Local Geodetic System: centroid of the written gcp coordinates."""
        gcp = [i for i, p in enumerate(self.points) if p.role == "gcp"]
        pts = self.measured_ecef_m[gcp] if gcp else np.array([p.ecef_m for p in self.points])
        return LocalFrame.at_centroid(pts)

    def truth(self) -> dict[str, Any]:
        s = self.settings
        lgs = self.lgs()
        ecef = np.array([p.ecef_m for p in self.points])
        llh = ecef_to_geodetic(ecef)
        images = []
        for im in self.images:
            step = max(1, s.truth_step_lines)
            lines = np.unique(np.append(np.arange(0, im.camera.lines, step), im.camera.lines - 1)).astype(float)
            t = im.time_of_line(lines)
            r, v, m = im.frames(t)
            opk = [np.degrees(opk_from_matrix(mk @ lgs.rotation_ecef_to_lgs.T)) for mk in m]
            images.append(
                {
                    "id": im.id,
                    "camera": im.camera.id,
                    "mounting_pitch_deg": im.camera.mounting_pitch_deg,
                    "first_line_time_s": s.epoch_s + im.first_line_time_s,
                    "samples": {
                        "line": lines.tolist(),
                        "time_s": (s.epoch_s + t).tolist(),
                        "position_ecef_m": r.tolist(),
                        "velocity_ecef_m_s": v.tolist(),
                        "camera_from_ecef": m.tolist(),
                        "omega_phi_kappa_lgs_deg": [list(map(float, o)) for o in opk],
                    },
                }
            )
        settings = _jsonable(asdict(s))
        if s.rpc is None:  # documents without RPC images stay as they were before issue 17
            del settings["rpc"]
        doc = {
            "schema": TRUTH_SCHEMA,
            "settings": settings,
            "conventions": {
                "time": "seconds of the UTC day: job time = epoch_s + simulator time",
                "camera_from_ecef": "rows x_c, y_c, z_c in ECEF: p_cam = M (p - S); x = -f X/Z, y = -f Y/Z",
                "omega_phi_kappa_lgs_deg": "M R_lgs^T = Rx(omega) Ry(phi) Rz(kappa), active matrices (solver.kernels convention)",
                "lgs": "east-north-up at the centroid of the written gcp coordinates",
            },
            "earth": {"gm_m3_s2": self.earth.gm_m3_s2, "radius_m": self.earth.radius_m, "omega_rad_s": self.earth.omega_rad_s, "zonal": {str(k): float(v) for k, v in self.earth.zonal.items()}},
            "orbit": {
                "semi_major_axis_m": self.semi_major_axis_m,
                "state0_ecef": self.orbit.state0.tolist(),
                "t_span_s": [self.orbit.t_min_s, self.orbit.t_max_s],
                "integrator": "DOP853 rtol 1e-12",
            },
            "cameras": self.true_cameras(),
            "attitude": _jsonable(self.platform.attitude.to_dict()),
            "terrain": _jsonable(self.terrain.to_dict()),
            "lgs": lgs.to_dict(),
            "points": [
                {
                    "id": p.id,
                    "role": p.role,
                    "group": p.group,
                    "ecef_m": p.ecef_m.tolist(),
                    "lon_deg": float(llh[i, 0]),
                    "lat_deg": float(llh[i, 1]),
                    "height_m": float(llh[i, 2]),
                    "survey_error_enu_m": self.survey_noise_enu_m[i].tolist() if p.role != "tie" else None,
                }
                for i, p in enumerate(self.points)
            ],
            "images": images,
            "observations": [
                {"image": self.images[o.image].id, "point": self.points[o.point].id, "line": o.line, "column": o.column, "chip": self.images[o.image].camera.chips[o.chip].id}
                for o in self.observations
            ],
        }
        if self.rpcs:
            doc["rpc_images"] = [rpc_truth(self.images[k], s.rpc.model, s.rpc.rpc_bias, rpc) for k, rpc in self.rpcs.items()]
        return doc


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_documents(scene: Scene, job_path: str | Path, truth_path: str | Path | None = None, indent: int | None = None) -> tuple[Path, Path]:
    """Write ``job.json`` and its truth file (default: ``job.truth.json`` beside it)."""
    job_path = Path(job_path)
    if truth_path is None:
        stem = job_path.name[:-5] if job_path.name.endswith(".json") else job_path.name
        truth_path = job_path.with_name(stem + ".truth.json")
    truth_path = Path(truth_path)
    job_path.write_text(json.dumps(scene.job(), indent=indent) + "\n")
    truth_path.write_text(json.dumps(scene.truth(), indent=indent) + "\n")
    return job_path, truth_path
