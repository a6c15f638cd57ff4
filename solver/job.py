"""The job document: one pydantic v2 schema shared by the CLI and the HTTP API.

Units and frames are in the field names: ``_mm`` millimetres in the focal plane, ``_px``
pixels, ``_s`` seconds, ``_m`` metres, ``_deg`` degrees. Image coordinates are (line, column)
with the origin at the centre of the top-left pixel (seed 001 Figure 1): the line number grows
with acquisition time, the column across the CCD.

Ground coordinates are given in any CRS (EPSG code such as ``"EPSG:32722"`` for UTM 22S,
``"EPSG:4618"`` for SAD69 geographic, ``"EPSG:4978"`` for WGS 84/ITRF ECEF, or a PROJ string);
axis order is always (x, y[, z]) = (easting, northing) or (longitude, latitude), as pyproj's
``always_xy``. Heights are ellipsoidal metres unless the CRS says otherwise.

Only structure and value ranges are checked here; cross references (unknown image, point,
camera), model names and degrees of freedom are checked by :func:`solver.validate.validate_job`
so that every problem in a document is reported at once.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

SCHEMA_VERSION = "1.0"

Role = Literal["gcp", "check", "tie"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Chip(_Strict):
    """One CCD chip of the focal plane (seed 001 eqs 1-3).

    The chip covers image columns ``first_column .. first_column + columns - 1``. Its scanline
    coordinate is ``y_s = (C - first_column - (columns - 1)/2) * pixel_mm`` and its camera
    coordinates ``x_c = dx_mm``, ``y_c = y_s + dy_mm`` (translations from the chip centre to the
    principal point, in the focal plane, mm).

    Chips may overlap (butted CCDs) and may extend beyond the delivered image: ``first_column``
    may be negative and the last column beyond the image's. A column covered by several chips
    belongs to the one whose centre column is nearest (the overlap split in the middle,
    :mod:`solver.chips`) unless its observation names its ``chip``.
    """

    id: str = Field(min_length=1, max_length=64)
    first_column: int
    columns: int = Field(gt=0)
    dx_mm: float = 0.0
    dy_mm: float = 0.0


class CameraRef(_Strict):
    """Reference to a camera stored in the server's camera library."""

    name: str = Field(min_length=1, max_length=128)
    version: int | None = Field(default=None, ge=1)


class IopCovariance(_Strict):
    """Covariance of interior-orientation parameters (as exported by a self-calibration)."""

    names: list[str]
    matrix: list[list[float]]

    @model_validator(mode="after")
    def _square(self) -> "IopCovariance":
        n = len(self.names)
        if len(self.matrix) != n or any(len(r) != n for r in self.matrix):
            raise ValueError(f"iop_covariance matrix must be {n} x {n}")
        return self


class Camera(_Strict):
    """A linear-array camera: focal plane, chips and timing.

    If ``chips`` is empty the image is one chip centred on the principal point covering every
    column. ``iop`` holds interior-orientation corrections (seed 001 section 4) by name, used
    as fixed values unless the job estimates them.
    """

    id: str = Field(min_length=1, max_length=64)
    ref: CameraRef | None = None
    focal_mm: float | None = Field(default=None, gt=0)
    pixel_mm: float | None = Field(default=None, gt=0)
    line_time_s: float | None = Field(default=None, gt=0)
    lines: int | None = Field(default=None, gt=0)
    columns: int | None = Field(default=None, gt=0)
    principal_point_mm: tuple[float, float] = (0.0, 0.0)
    chips: list[Chip] = Field(default_factory=list)
    mounting_pitch_deg: float = Field(
        default=0.0,
        ge=-60,
        le=60,
        description="nominal along-track tilt of the camera (backward PRISM -23.8, forward +23.8)",
    )
    iop: dict[str, Any] = Field(default_factory=dict)
    iop_covariance: IopCovariance | None = None
    iop_use: Literal["fixed", "weighted"] = Field(
        default="fixed",
        description="reuse of a calibration: 'fixed' holds iop values; 'weighted' makes the values "
        "estimated in this job (options.self_calibration) weighted by iop_covariance",
    )

    @model_validator(mode="after")
    def _complete_unless_ref(self) -> "Camera":
        if self.ref is None:
            missing = [
                n
                for n in ("focal_mm", "pixel_mm", "line_time_s", "lines", "columns")
                if getattr(self, n) is None
            ]
            if missing:
                raise ValueError(f"camera {self.id!r} needs {', '.join(missing)} (or a library ref)")
        return self


class ModelChoice(_Strict):
    """Platform model of an image: a registered name and its options.

    Options by model (see ``pba models``): ON1/ON2/MT8/MT12 ``omega_deg``/``phi_deg`` (held
    values; default: 0 and the camera's mounting pitch); GENERAL ``orders`` {X,Y,Z,omega,phi,
    kappa: 0..3}.
    """

    name: str = Field(min_length=1, max_length=32)
    options: dict[str, Any] = Field(default_factory=dict)


class StateVector(_Strict):
    """Platform state in the Earth-fixed frame (WGS 84 / ITRF ECEF)."""

    time_s: float = Field(description="seconds, on the same time scale as first_line_time_s")
    position_ecef_m: tuple[float, float, float]
    velocity_ecef_m_s: tuple[float, float, float]


class AttitudeSample(_Strict):
    """Measured platform attitude at one epoch (star tracker / AOCS telemetry), as roll, pitch
    and yaw of the platform body relative to the orbital frame of the orbit-attitude models
    (x along track, z radial up; M = Ry(mounting) Rx(roll) Ry(pitch) Rz(yaw) R_orbit, docs/models.md
    section 10), degrees. Used with ``options.attitude`` by the OA-* and PASS-* models."""

    time_s: float = Field(description="seconds, on the same time scale as first_line_time_s")
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


class ApproxState(_Strict):
    """Approximate perspective-centre state at the image's first line (line 0), ECEF.

    From the image header or ephemeris. Used to initialise every platform model (the angles are
    then found by a resection on the control points). ``attitude_deg`` optionally gives
    approximate (omega, phi, kappa) in the local geodetic frame.

    With ``sigma_position_m`` (and optionally ``sigma_velocity_m_s``) the state also enters the
    adjustment as a weighted observation of the model's position (and velocity) at line 0
    (seed 001 eqs 38-43: state = ephemeris value + correction with weighted constraints).
    """

    position_ecef_m: tuple[float, float, float]
    velocity_ecef_m_s: tuple[float, float, float]
    attitude_deg: tuple[float, float, float] | None = None
    sigma_position_m: float | None = Field(default=None, gt=0)
    sigma_velocity_m_s: float | None = Field(default=None, gt=0)


class Image(_Strict):
    """One pushbroom image."""

    id: str = Field(min_length=1, max_length=64)
    camera: str = Field(min_length=1, max_length=64)
    model: ModelChoice
    approx_state: ApproxState | None = None
    first_line_time_s: float | None = None
    ephemeris: list[StateVector] = Field(default_factory=list)
    attitude: list[AttitudeSample] = Field(
        default_factory=list,
        description="measured attitude samples (roll, pitch, yaw relative to the orbital frame); "
        "weighted observations of the orbit-attitude and pass models with options.attitude",
    )
    initial: dict[str, float] = Field(
        default_factory=dict, description="initial parameter values by model parameter name"
    )

    @field_validator("initial")
    @classmethod
    def _finite(cls, v: dict[str, float]) -> dict[str, float]:
        for k, x in v.items():
            if not math.isfinite(x):
                raise ValueError(f"initial value {k!r} is not finite")
        return v


class GroundPoint(_Strict):
    """A ground point: control (gcp), check, or tie (unknown coordinates).

    ``coordinates`` in ``crs`` (or the document's default CRS), x/y order; ``sigma_m`` the
    survey standard deviations along local east, north, up in metres. A gcp with ``sigma_m``
    enters as a weighted constraint unless the options say ``control: fixed``; a gcp without
    sigma is fixed. Tie points may omit coordinates (they are then intersected).
    """

    id: str = Field(min_length=1, max_length=64)
    role: Role
    coordinates: tuple[float, float, float] | None = None
    crs: str | None = None
    sigma_m: tuple[float, float, float] | None = None

    @field_validator("sigma_m")
    @classmethod
    def _positive(cls, v: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if v is not None and any(s <= 0 for s in v):
            raise ValueError("sigmas must be positive")
        return v

    @model_validator(mode="after")
    def _coords_needed(self) -> "GroundPoint":
        if self.role != "tie" and self.coordinates is None:
            raise ValueError(f"point {self.id!r} with role {self.role!r} needs coordinates")
        return self


class ImageObservation(_Strict):
    """A measured image point: (line, column) in pixels with its standard deviation.

    ``chip`` optionally names the CCD chip (its ``id`` in the camera's ``chips``; "1" for a camera
    without chips) that imaged the point, for columns where chips overlap; the column must lie on
    that chip. Without it the column's chip follows the rule of :mod:`solver.chips` (the covering
    chip whose centre column is nearest).
    """

    image: str = Field(min_length=1, max_length=64)
    point: str = Field(min_length=1, max_length=64)
    line: float
    column: float
    sigma_px: float = Field(default=0.5, gt=0)
    chip: str | None = Field(default=None, min_length=1, max_length=64)


LineRole = Literal["control", "check"]
LineForm = Literal["y=ax+b", "x=a'y+b'"]


class LineImagePoint(_Strict):
    """A measured image point of a straight line: (line, column) in pixels."""

    line: float
    column: float


class FittedImageLine(_Strict):
    """An image line given by fitted parameters, in pixel coordinates x = image line (along
    track, grows with time) and y = image column.

    ``form`` ``"y=ax+b"``: column = a * line + b (lines running mostly along the image lines
    axis); ``"x=a'y+b'"``: line = a * column + b. ``sigma_a`` is dimensionless (px/px),
    ``sigma_b`` in pixels, ``correlation`` that of a and b (the intercept is at x = 0 or y = 0,
    so a fit far from the axis has strongly correlated a and b).
    """

    form: LineForm
    a: float
    b: float
    sigma_a: float = Field(gt=0)
    sigma_b: float = Field(gt=0)
    correlation: float = Field(default=0.0, gt=-1, lt=1)


class LineObservation(_Strict):
    """One image of a straight line: two or more measured image points (each with ``sigma_px``
    on line and column), or the fitted parameters of the image line (exactly one of the two)."""

    image: str = Field(min_length=1, max_length=64)
    points: list[LineImagePoint] = Field(default_factory=list)
    sigma_px: float = Field(default=0.5, gt=0)
    fitted: FittedImageLine | None = None


class GroundLine(_Strict):
    """A straight line in object space, given by two of its points, and its images.

    ``endpoints`` in ``crs`` (or the document's default CRS), x/y order like points;
    ``sigma_m`` the survey standard deviations of each endpoint along local east, north, up in
    metres (without it the line is exact). ``role`` ``control`` lines enter the adjustment,
    ``check`` lines are only compared with the adjusted orientation. The endpoints need not be
    the ends of what is seen in the image: any two distinct points of the line will do.
    """

    id: str = Field(min_length=1, max_length=64)
    role: LineRole = "control"
    endpoints: tuple[tuple[float, float, float], tuple[float, float, float]]
    crs: str | None = None
    sigma_m: tuple[float, float, float] | None = None
    observations: list[LineObservation] = Field(default_factory=list)

    @field_validator("sigma_m")
    @classmethod
    def _positive(cls, v: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if v is not None and any(s <= 0 for s in v):
            raise ValueError("sigmas must be positive")
        return v


class AttitudeOptions(_Strict):
    """Use the images' ``attitude`` samples as weighted observations of the attitude angles
    (orbit-attitude and pass models): each distinct sample within the time span of the images
    sharing an attitude block observes roll, pitch and yaw at its own epoch."""

    sigma_deg: tuple[float, float, float] = Field(description="roll, pitch, yaw standard deviations (deg)")

    @field_validator("sigma_deg")
    @classmethod
    def _positive(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if any(x <= 0 for x in v):
            raise ValueError("sigmas must be positive")
        return v


class EphemerisOptions(_Strict):
    """Use each image's ``ephemeris`` (state vectors) for its line-0 state (seed 001 section 5).

    The state vectors are interpolated to ``first_line_time_s`` (Hermite with positions and
    velocities over the ``nodes`` nearest samples, :mod:`solver.ephemeris`) and replace the
    image's ``approx_state`` position and velocity. With ``sigma_position_m`` (and optionally
    ``sigma_velocity_m_s``) they also enter the adjustment as weighted observations of the
    model's state: state = ephemeris value + correction (seed 001 eqs 38-43). Without sigmas the
    interpolated state only initialises the models.
    """

    sigma_position_m: float | None = Field(default=None, gt=0)
    sigma_velocity_m_s: float | None = Field(default=None, gt=0)
    nodes: int = Field(default=4, ge=2, le=8, description="samples used around the epoch")

    @model_validator(mode="after")
    def _velocity_needs_position(self) -> "EphemerisOptions":
        if self.sigma_velocity_m_s is not None and self.sigma_position_m is None:
            raise ValueError("sigma_velocity_m_s needs sigma_position_m")
        return self


class SelfCalibration(_Strict):
    """Interior-orientation parameters to estimate (docs/models.md section 8, seed 001).

    ``estimate``: optical names (x0, y0, df, k1, k2, sy) and chip names (a0, b0, a1, b1, delta:
    every chip but the master; ``a0@3`` a single chip). ``sigmas``: weighted constraints by
    name (mm or unitless; null = free); defaults a0, b0 1.5 px, a1, b1 300 ppm (seed 001).
    ``significance_analysis``: drop, one at a time, the parameter whose |estimate| is below its
    sigma, re-adjusting each time (seed 001 Figure 14).
    """

    estimate: list[str] = Field(min_length=1)
    cameras: list[str] | None = None
    master_chip: dict[str, str] = Field(default_factory=dict)
    sigmas: dict[str, float | None] = Field(default_factory=dict)
    exclude: list[str] = Field(
        default_factory=list, description="'<camera id>/<parameter>' left out of the estimation (held)"
    )
    significance_analysis: bool = False
    significance_threshold: float = Field(
        default=1.0,
        gt=0,
        description="drop while |estimate| < threshold * sigma (seed 001: 1; 3 removes the spurious "
        "chip bendings measured in docs/experiments.md, seed001 section)",
    )


class SolverOptions(_Strict):
    """How to solve and what to report."""

    max_iterations: int = Field(default=50, ge=1, le=1000)
    function_tolerance: float = Field(default=1e-10, gt=0)
    parameter_tolerance: float = Field(default=1e-10, gt=0)
    control: Literal["weighted", "fixed"] = "weighted"
    sigma0_apriori: float = Field(default=1.0, gt=0)
    alpha: float = Field(default=0.05, gt=0, lt=0.5)
    correlation_threshold: float = Field(default=0.75, gt=0, le=1)
    covariance: bool = True
    loss: Literal["none", "huber", "cauchy"] = "none"
    loss_scale: float = Field(default=3.0, gt=0)
    kernel: Literal["auto", "python"] = "auto"
    self_calibration: SelfCalibration | None = None
    models: list[str] = Field(
        default_factory=list,
        description="model comparison: adjust the same observations with each of these models",
    )
    line_model: Literal["rigorous", "equivalent_planes"] = Field(
        default="rigorous",
        description="straight-line observations: exact pushbroom distance of each image point "
        "(rigorous) or the equivalent planes model of seed 002 eqs 1-4 (equivalent_planes)",
    )
    line_correction: Literal["iterated", "initial", "none"] = Field(
        default="iterated",
        description="pushbroom correction of the equivalent planes model (seed 002 eqs 5-8): "
        "recomputed from the solution until it settles (iterated), computed once from the "
        "initial orientation as in the paper (initial), or not applied (none)",
    )
    ephemeris: EphemerisOptions | None = Field(
        default=None,
        description="interpolate each image's ephemeris to its first line and use it as the "
        "line-0 state (weighted observation when sigmas are given; seed 001 eqs 38-43)",
    )
    attitude: AttitudeOptions | None = Field(
        default=None,
        description="the images' attitude samples as weighted observations of roll, pitch and yaw "
        "(orbit-attitude and pass models)",
    )


class Job(_Strict):
    """A complete adjustment job."""

    schema_version: Literal["1.0"] = SCHEMA_VERSION
    name: str = Field(default="job", max_length=200)
    crs: str = Field(default="EPSG:4326", description="default CRS of ground coordinates")
    cameras: list[Camera] = Field(min_length=1)
    images: list[Image] = Field(min_length=1)
    points: list[GroundPoint] = Field(default_factory=list)
    observations: list[ImageObservation] = Field(default_factory=list)
    lines: list[GroundLine] = Field(
        default_factory=list, description="straight lines (control or check) and their image observations"
    )
    options: SolverOptions = Field(default_factory=SolverOptions)


def load_job(data: dict[str, Any] | str | bytes) -> Job:
    """Parse a job from a dict or JSON text (raises pydantic.ValidationError)."""
    if isinstance(data, (str, bytes)):
        return Job.model_validate_json(data)
    return Job.model_validate(data)
