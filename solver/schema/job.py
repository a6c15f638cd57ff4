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
camera), model names and degrees of freedom are checked by :func:`solver.engine.validate.validate_job`
so that every problem in a document is reported at once.
"""

from __future__ import annotations

import copy
import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict, ValidationInfo, field_validator, model_validator
from pydantic.dataclasses import dataclass as pydantic_dataclass
from typing_extensions import TypedDict

from solver.schema.iop_names import camera_iop_names

SCHEMA_VERSION = "1.0"

Role = Literal["gcp", "check", "tie"]

# ---- number types: strict (no "481.8" -> 481.8, no true -> 1), finite, of plausible size ------
MAX_ABS = 1e15  # no number of a job is larger: squares and products stay finite
MAX_COORDINATE = 1e8  # ground coordinates (m or deg) in any CRS: beyond this none is on Earth
MAX_ANGLE_DEG = 360.0
MAX_TIME_S = 1e10  # |epoch| in seconds on any time scale (GPS seconds are 1.4e9)
MIN_SIGMA_PX = 1e-6  # smaller image sigmas give weights that swamp every other observation
MIN_SIGMA_M = 1e-6  # 1 micrometre: survey, state and endpoint standard deviations
MIN_FOCAL_MM = 0.1  # focal length after the df correction
MAX_FOCAL_MM = 1e5
MIN_STATE_RADIUS_M = 6.3e6  # a platform state closer to the geocentre is inside the Earth
MAX_STATE_RADIUS_M = 1e8  # four times the geostationary radius
MAX_SPEED_M_S = 1e5
MAX_LINES = 10**8
MAX_COLUMNS = 10**6
MAX_COMPARED_MODELS = 16
MAX_IOP = 64  # names of an iop_covariance (optical + 8 chips x 5 is 46)


def _num(**bounds: float) -> Any:
    """A strict finite JSON number within +-MAX_ABS (an integer is accepted), with ``bounds``
    (ge, gt, le, lt) added."""
    limits = {"ge": -MAX_ABS, "le": MAX_ABS, **bounds}
    if "gt" in bounds:
        limits.pop("ge")
    if "lt" in bounds:
        limits.pop("le")
    return Annotated[float, Strict(), Field(allow_inf_nan=False, **limits)]


def _int(**bounds: int) -> Any:
    """A strict JSON integer (3.0, "3" and true are refused) with ``bounds``."""
    return Annotated[int, Strict(), Field(**bounds)]


Num = _num()
Coordinate = _num(ge=-MAX_COORDINATE, le=MAX_COORDINATE)
AngleDeg = _num(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)
TimeS = _num(ge=-MAX_TIME_S, le=MAX_TIME_S)
SigmaM = _num(ge=MIN_SIGMA_M, le=1e7)
SigmaPx = _num(ge=MIN_SIGMA_PX, le=1e6)
Bool = Annotated[bool, Strict()]
Xyz = tuple[Num, Num, Num]


def _platform_position(v: tuple[float, float, float]) -> tuple[float, float, float]:
    """A platform position (ECEF m) outside the Earth and within MAX_STATE_RADIUS_M."""
    r = math.sqrt(sum(x * x for x in v))
    if r < MIN_STATE_RADIUS_M:
        raise ValueError(
            f"the position is {r:.6g} m from the geocentre: inside the Earth (ECEF metres expected, "
            f"at least {MIN_STATE_RADIUS_M:g} m)"
        )
    if r > MAX_STATE_RADIUS_M:
        raise ValueError(f"the position is {r:.6g} m from the geocentre: beyond {MAX_STATE_RADIUS_M:g} m")
    return v


def _platform_velocity(v: tuple[float, float, float]) -> tuple[float, float, float]:
    """A platform velocity (ECEF m/s) below MAX_SPEED_M_S."""
    speed = math.sqrt(sum(x * x for x in v))
    if speed > MAX_SPEED_M_S:
        raise ValueError(f"speed {speed:.6g} m/s is beyond {MAX_SPEED_M_S:g} m/s (m/s expected)")
    return v


PositionEcefM = Annotated[Xyz, AfterValidator(_platform_position)]
VelocityEcefMS = Annotated[Xyz, AfterValidator(_platform_velocity)]


def _unique(values: list[str], what: str) -> list[str]:
    """``values``, or ValueError naming the first one listed twice."""
    seen: set[str] = set()
    for v in values:
        if v in seen:
            raise ValueError(f"{what} {v!r} is listed twice")
        seen.add(v)
    return values


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


_Id = Annotated[str, Field(min_length=1, max_length=64)]  # an id or a reference to one


class Chip(_Strict):
    """One CCD chip of the focal plane (seed 001 eqs 1-3).

    The chip covers image columns ``first_column .. first_column + columns - 1``. Its scanline
    coordinate is ``y_s = (C - first_column - (columns - 1)/2) * pixel_mm`` and its camera
    coordinates ``x_c = dx_mm``, ``y_c = y_s + dy_mm`` (translations from the chip centre to the
    principal point, in the focal plane, mm).

    Chips may overlap (butted CCDs) and may extend beyond the delivered image: ``first_column``
    may be negative and the last column beyond the image's. A column covered by several chips
    belongs to the one whose centre column is nearest (the overlap split in the middle,
    :mod:`solver.geometry.sensor`) unless its observation names its ``chip``.
    """

    id: str = Field(min_length=1, max_length=64)
    first_column: _int(ge=-MAX_COLUMNS, le=MAX_COLUMNS)
    columns: _int(gt=0, le=MAX_COLUMNS)
    dx_mm: _num(ge=-1e3, le=1e3) = 0.0
    dy_mm: _num(ge=-1e3, le=1e3) = 0.0


class CameraRef(_Strict):
    """Reference to a camera stored in the server's camera library."""

    name: str = Field(min_length=1, max_length=128)
    version: _int(ge=1, le=2**31) | None = None


class IopCovariance(_Strict):
    """Covariance of interior-orientation parameters (as exported by a self-calibration)."""

    names: list[str] = Field(min_length=1, max_length=MAX_IOP)
    matrix: list[list[Num]] = Field(max_length=MAX_IOP)

    @field_validator("names")
    @classmethod
    def _distinct(cls, v: list[str]) -> list[str]:
        return _unique(v, "interior-orientation parameter")

    @model_validator(mode="after")
    def _covariance(self) -> "IopCovariance":
        n = len(self.names)
        if len(self.matrix) != n or any(len(r) != n for r in self.matrix):
            raise ValueError(f"iop_covariance matrix must be {n} x {n}")
        m = np.array(self.matrix, dtype=float)
        if not np.allclose(m, m.T, rtol=1e-6, atol=0.0):
            raise ValueError("iop_covariance matrix is not symmetric")
        try:
            np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            raise ValueError(
                "iop_covariance matrix is not positive definite (every variance must be positive "
                "and every correlation within -1..1)"
            ) from None
        return self


class Camera(_Strict):
    """A linear-array camera: focal plane, chips and timing.

    If ``chips`` is empty the image is one chip centred on the principal point covering every
    column. ``iop`` holds interior-orientation corrections (seed 001 section 4) by name, used
    as fixed values unless the job estimates them.
    """

    id: str = Field(min_length=1, max_length=64)
    ref: CameraRef | None = None
    focal_mm: _num(ge=MIN_FOCAL_MM, le=MAX_FOCAL_MM) | None = None
    pixel_mm: _num(ge=1e-6, le=10.0) | None = None
    line_time_s: _num(ge=1e-9, le=10.0) | None = None
    lines: _int(gt=0, le=MAX_LINES) | None = None
    columns: _int(gt=0, le=MAX_COLUMNS) | None = None
    principal_point_mm: tuple[_num(ge=-1e3, le=1e3), _num(ge=-1e3, le=1e3)] = (0.0, 0.0)
    chips: list[Chip] = Field(default_factory=list)
    mounting_pitch_deg: Num = Field(
        default=0.0,
        ge=-60,
        le=60,
        description="nominal along-track tilt of the camera (backward PRISM -23.8, forward +23.8)",
    )
    iop: dict[str, _num(ge=-1e6, le=1e6)] = Field(
        default_factory=dict,
        description="interior-orientation values by name: x0, y0, df, k1, k2, sy and per chip "
        "a0, b0, a1, b1, delta as '<name>@<chip id>'",
    )
    iop_covariance: IopCovariance | None = None
    iop_use: Literal["fixed", "weighted"] = Field(
        default="fixed",
        description="reuse of a calibration: 'fixed' holds iop values; 'weighted' makes the values "
        "estimated in this job (options.self_calibration) weighted by iop_covariance",
    )

    @field_validator("iop")
    @classmethod
    def _iop_values(cls, v: dict[str, float], info: ValidationInfo) -> dict[str, float]:
        _known_iop(v, info)
        focal = info.data.get("focal_mm")
        if focal is not None and focal + v.get("df", 0.0) < MIN_FOCAL_MM:
            raise ValueError(
                f"focal_mm + df = {focal + v.get('df', 0.0):.6g} mm: the corrected focal length "
                f"must be at least {MIN_FOCAL_MM} mm"
            )
        return v

    @field_validator("iop_covariance")
    @classmethod
    def _covariance_names(cls, v: IopCovariance | None, info: ValidationInfo) -> IopCovariance | None:
        if v is not None:
            _known_iop(v.names, info)
        return v

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


def _known_iop(names: Any, info: ValidationInfo) -> None:
    """ValueError naming the first IOP name that is not one of the camera's (chips as given)."""
    chips = info.data.get("chips")
    if chips is None:  # the chips themselves are invalid (reported on their own)
        return
    known = camera_iop_names([c.id for c in chips])
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(
            f"unknown interior-orientation parameter {unknown[0]!r} (known: x0, y0, df, k1, k2, sy "
            f"and a0, b0, a1, b1, delta @ chip id {', '.join(c.id for c in chips) or '1'})"
        )


Element = Literal["X", "Y", "Z", "omega", "phi", "kappa"]


# Options of a platform model; which ones a model takes is in ``pba models`` (others are refused
# by validation). Functional form: "pass" is a Python keyword.
ModelOptions = TypedDict(
    "ModelOptions",
    {
        "orders": dict[Element, _int(ge=-1, le=3)],
        "omega_deg": AngleDeg,
        "phi_deg": AngleDeg,
        "kappa_deg": AngleDeg,
        "pass": _Id,
        "attitude": Annotated[str, Field(min_length=1, max_length=32)],
    },
    total=False,
)
ModelOptions.__pydantic_config__ = ConfigDict(extra="forbid", allow_inf_nan=False)  # type: ignore[attr-defined]


class ModelChoice(_Strict):
    """Platform model of an image: a registered name and its options.

    Options by model (see ``pba models``): ON1/ON2/MT8/MT12 ``omega_deg``/``phi_deg`` (held
    values; default: 0 and the camera's mounting pitch); GENERAL ``orders`` {X,Y,Z,omega,phi,
    kappa: -1..3} and ``<angle>_deg`` of held angles; OA-* ``orders``; PASS-* ``orders``,
    ``pass``, ``attitude``.
    """

    name: str = Field(min_length=1, max_length=32)
    options: ModelOptions = Field(default_factory=dict)  # type: ignore[arg-type]


class StateVector(_Strict):
    """Platform state in the Earth-fixed frame (WGS 84 / ITRF ECEF)."""

    time_s: TimeS = Field(description="seconds, on the same time scale as first_line_time_s")
    position_ecef_m: PositionEcefM
    velocity_ecef_m_s: VelocityEcefMS


class AttitudeSample(_Strict):
    """Measured platform attitude at one epoch (star tracker / AOCS telemetry), as roll, pitch
    and yaw of the platform body relative to the orbital frame of the orbit-attitude models
    (x along track, z radial up; M = Ry(mounting) Rx(roll) Ry(pitch) Rz(yaw) R_orbit, docs/models.md
    section 10), degrees. Used with ``options.attitude`` by the OA-* and PASS-* models."""

    time_s: TimeS = Field(description="seconds, on the same time scale as first_line_time_s")
    roll_deg: AngleDeg
    pitch_deg: AngleDeg
    yaw_deg: AngleDeg


class ApproxState(_Strict):
    """Approximate perspective-centre state at the image's first line (line 0), ECEF.

    From the image header or ephemeris. Used to initialise every platform model (the angles are
    then found by a resection on the control points). ``attitude_deg`` optionally gives
    approximate (omega, phi, kappa) in the local geodetic frame.

    With ``sigma_position_m`` (and optionally ``sigma_velocity_m_s``) the state also enters the
    adjustment as a weighted observation of the model's position (and velocity) at line 0
    (seed 001 eqs 38-43: state = ephemeris value + correction with weighted constraints).
    """

    position_ecef_m: PositionEcefM
    velocity_ecef_m_s: VelocityEcefMS
    attitude_deg: tuple[AngleDeg, AngleDeg, AngleDeg] | None = None
    sigma_position_m: SigmaM | None = None
    sigma_velocity_m_s: _num(ge=1e-9, le=1e5) | None = None


RpcCoefficients = Annotated[list[Num], Field(min_length=20, max_length=20)]


class Rpc(_Strict):
    """An RPC00B sensor model (``images[].rpc``): GDAL's RPC metadata field names in lower case,
    20 coefficients per polynomial in the RPC00B term order. ``pixel_convention`` ``"center"``
    (ours, default: the centre of the top-left pixel is line 0, column 0) or ``"gdal"`` (the
    top-left pixel's corner is 0: ``line_off`` and ``samp_off`` are half a pixel larger, what
    GDAL's RPC transformer uses); converted once when the job is assembled."""

    line_off: Num
    samp_off: Num
    lat_off: _num(ge=-90, le=90)
    long_off: _num(ge=-360, le=360)
    height_off: _num(ge=-1e5, le=1e5)
    line_scale: Num
    samp_scale: Num
    lat_scale: Num
    long_scale: Num
    height_scale: Num
    line_num_coeff: RpcCoefficients
    line_den_coeff: RpcCoefficients
    samp_num_coeff: RpcCoefficients
    samp_den_coeff: RpcCoefficients
    err_bias: Num = -1.0
    err_rand: Num = -1.0
    pixel_convention: Literal["center", "gdal"] = "center"


class BiasPrior(_Strict):
    """A weighted a-priori value of one RPC bias parameter (report units: px or px/px)."""

    value: _num(ge=-1e9, le=1e9) = 0.0
    sigma: _num(gt=0, le=1e9)


class SensorOrigin(_Strict):
    """Where an image's camera, ephemeris and attitude were read from (vendor metadata, by ``pba
    import-sensor`` or ``pba job --sensor``) and what the reading did to them: conversions (an
    inertial velocity made Earth-fixed) and samples it did not use. Informative: the solver does
    not read it, and the report repeats it (``images[].sensor``)."""

    file: str = Field(min_length=1, max_length=4096)
    satellite: str = Field(default="", max_length=200)
    notes: list[Annotated[str, Field(max_length=4000)]] = Field(
        default_factory=list, max_length=200, description="what the reader converted or did not use, one sentence each"
    )


class Image(_Strict):
    """One pushbroom image: a camera with a platform model, or an RPC (``rpc``) with an RPC
    bias model (RPC-SHIFT, RPC-DRIFT, RPC-AFFINE), which needs no camera."""

    id: str = Field(min_length=1, max_length=64)
    camera: str | None = Field(
        default=None,
        min_length=1,
        max_length=64,
        description='id of a camera of cameras[]; or, in place, {"ref": {"name": "prism-nadir"}} '
        "(a library camera or sensor preset, added to cameras[]); omitted for an RPC image",
    )
    rpc: Rpc | None = Field(default=None, description="RPC00B sensor model (RPC bias models only)")
    bias_prior: dict[str, BiasPrior] = Field(
        default_factory=dict,
        description="RPC images: weighted a-priori values of bias parameters by name "
        "(a0, a_line, a_column, b0, b_line, b_column)",
    )
    model: ModelChoice
    approx_state: ApproxState | None = None
    first_line_time_s: TimeS | None = None
    ephemeris: list[StateVector] = Field(default_factory=list)
    attitude: list[AttitudeSample] = Field(
        default_factory=list,
        description="measured attitude samples (roll, pitch, yaw relative to the orbital frame); "
        "weighted observations of the orbit-attitude and pass models with options.attitude",
    )
    attitude_base: list[AttitudeSample] = Field(
        default_factory=list,
        max_length=100_000,
        description="the delivered attitude (roll, pitch, yaw relative to the orbital frame, increasing epochs, 2 samples "
        "at least), interpolated linearly in the angles between its samples (beyond them: the end intervals extended): "
        "the orbit-attitude and pass models' angle polynomials are then a correction added to it (constant data, "
        "not estimated; pba job --sensor writes the vendor's attitude here)",
    )
    sensor: SensorOrigin | None = Field(
        default=None, description="the vendor metadata the image was read from, and what its reading converted or dropped"
    )
    initial: dict[str, _num(ge=-1e9, le=1e9)] = Field(
        default_factory=dict, description="initial parameter values by model parameter name"
    )


MAX_DEM_CELLS = 4_000_000  # as solver.geometry.dem.MAX_JOB_CELLS: a 60 x 60 km scene at 30 m


class DemGrid(_Strict):
    """A DEM carried in the job (``pba job --dem`` writes it): WGS 84 ellipsoidal heights in
    metres on a grid of ``rows`` x ``columns`` cells of the horizontal ``crs``, under the affine
    ``transform`` (a, b, c, d, e, f: x = c + a col + b row, y = f + d col + e row at the cells'
    corners), as base64 float32 little-endian values, row-major, NaN where there is no data."""

    crs: str = Field(min_length=1, max_length=8192)
    transform: tuple[Num, Num, Num, Num, Num, Num]
    rows: _int(ge=2, le=MAX_DEM_CELLS)
    columns: _int(ge=2, le=MAX_DEM_CELLS)
    heights: str = Field(max_length=4 * ((4 * MAX_DEM_CELLS + 2) // 3), description="base64 of rows x columns float32 (little-endian), ellipsoidal metres")
    source: str = Field(default="DEM", max_length=1024, description="the file the grid was read from")
    vertical: str = Field(default="WGS 84 ellipsoidal heights", max_length=512,
                          description="the file's vertical datum and its conversion to ellipsoidal heights")

    @model_validator(mode="after")
    def _cells(self) -> "DemGrid":
        if self.rows * self.columns > MAX_DEM_CELLS:
            raise ValueError(f"a DEM grid of at most {MAX_DEM_CELLS} cells")
        return self


class DemHeights(_Strict):
    """DEM heights as observations of the tie points (docs/datum.md): the DEM's height at each
    tie point's horizontal position, re-read as the point moves, weighted by the DEM's accuracy,
    the local slope and the DEM's cell against the images' pixels."""

    grid: DemGrid
    sigma_m: SigmaM = Field(description="the DEM's vertical accuracy, one sigma (SRTM about 6 m, Copernicus DEM about 3 m)")
    loss: Literal["huber", "cauchy", "none"] = Field(
        default="huber", description="robust loss of the DEM heights (points on roofs, trees or water are not on the DEM's surface)")
    loss_scale: _num(gt=0, le=1e3) = Field(default=3.0, description="where the loss starts, in sigmas of a DEM height")
    excluded: list[_Id] = Field(default_factory=list, description="tie points whose DEM height is not used (data snooping's removals)")


class GroundPoint(_Strict):
    """A ground point: control (gcp), check, or tie (unknown coordinates).

    ``coordinates`` in ``crs`` (or the document's default CRS), x/y order; ``sigma_m`` the
    survey standard deviations along local east, north, up in metres. A gcp with ``sigma_m``
    enters as a weighted constraint unless the options say ``control: fixed``; a gcp without
    sigma is fixed. Tie points may omit coordinates (they are then intersected).
    """

    id: str = Field(min_length=1, max_length=64)
    role: Role
    coordinates: tuple[Coordinate, Coordinate, Coordinate] | None = None
    crs: str | None = Field(default=None, min_length=1, max_length=4096)
    sigma_m: tuple[SigmaM, SigmaM, SigmaM] | None = None

    @model_validator(mode="after")
    def _coords_needed(self) -> "GroundPoint":
        if self.role != "tie" and self.coordinates is None:
            raise ValueError(f"point {self.id!r} with role {self.role!r} needs coordinates")
        return self


# A slotted pydantic dataclass, not a model: a job holds up to millions of these, and a model
# instance carries a dict and a set of its fields (about 1.1 kB each, 1.1 GB per million
# observations, and 3x the validation time); validation, errors and the schema are the same.
@pydantic_dataclass(slots=True, config=_Strict.model_config)
class ImageObservation:
    """A measured image point: (line, column) in pixels with its standard deviation.

    ``chip`` optionally names the CCD chip (its ``id`` in the camera's ``chips``; "1" for a camera
    without chips) that imaged the point, for columns where chips overlap; the column must lie on
    that chip. Without it the column's chip follows the rule of :mod:`solver.geometry.sensor` (the covering
    chip whose centre column is nearest).
    """

    image: _Id
    point: _Id
    line: _num(ge=-MAX_LINES, le=MAX_LINES)
    column: _num(ge=-MAX_COLUMNS, le=MAX_COLUMNS)
    sigma_px: SigmaPx = 0.5
    chip: _Id | None = None

    def reweighted(self, sigma_px: float) -> ImageObservation:
        """A copy with standard deviation ``sigma_px``, not validated (an inflated weight may pass
        the document's bound)."""
        out = copy.copy(self)
        out.sigma_px = sigma_px
        return out


LineRole = Literal["control", "check"]
LineForm = Literal["y=ax+b", "x=a'y+b'"]


class LineImagePoint(_Strict):
    """A measured image point of a straight line: (line, column) in pixels."""

    line: _num(ge=-MAX_LINES, le=MAX_LINES)
    column: _num(ge=-MAX_COLUMNS, le=MAX_COLUMNS)


class FittedImageLine(_Strict):
    """An image line given by fitted parameters, in pixel coordinates x = image line (along
    track, grows with time) and y = image column.

    ``form`` ``"y=ax+b"``: column = a * line + b (lines running mostly along the image lines
    axis); ``"x=a'y+b'"``: line = a * column + b. ``sigma_a`` is dimensionless (px/px),
    ``sigma_b`` in pixels, ``correlation`` that of a and b (the intercept is at x = 0 or y = 0,
    so a fit far from the axis has strongly correlated a and b).
    """

    form: LineForm
    a: _num(ge=-1e9, le=1e9)
    b: _num(ge=-1e9, le=1e9)
    sigma_a: _num(ge=1e-12, le=1e6)
    sigma_b: SigmaPx
    correlation: _num(gt=-1, lt=1) = 0.0


class LineObservation(_Strict):
    """One image of a straight line: two or more measured image points (each with ``sigma_px``
    on line and column), or the fitted parameters of the image line (exactly one of the two)."""

    image: str = Field(min_length=1, max_length=64)
    points: list[LineImagePoint] = Field(default_factory=list)
    sigma_px: SigmaPx = 0.5
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
    endpoints: tuple[
        tuple[Coordinate, Coordinate, Coordinate], tuple[Coordinate, Coordinate, Coordinate]
    ]
    crs: str | None = Field(default=None, min_length=1, max_length=4096)
    sigma_m: tuple[SigmaM, SigmaM, SigmaM] | None = None
    observations: list[LineObservation] = Field(default_factory=list)


class AttitudeOptions(_Strict):
    """Use the images' ``attitude`` samples as weighted observations of the attitude angles
    (orbit-attitude and pass models): each distinct sample within the time span of the images
    sharing an attitude block observes roll, pitch and yaw at its own epoch. Telemetry errs
    mostly by one bias per block and angle: ``bias_sigma_deg`` models it (docs/models.md
    section 10), ``sigma_deg`` is then the white noise of each sample."""

    sigma_deg: tuple[_num(ge=1e-9, le=360), _num(ge=1e-9, le=360), _num(ge=1e-9, le=360)] = Field(
        description="roll, pitch, yaw standard deviations (deg); with bias_sigma_deg, of the white "
        "part of each sample's error"
    )
    bias_sigma_deg: tuple[_num(ge=0, le=360), _num(ge=0, le=360), _num(ge=0, le=360)] | None = Field(
        default=None,
        description="roll, pitch, yaw standard deviations (deg) of an error common to every sample "
        "of an attitude block (one bias per block and angle): the samples of one block and angle "
        "then have the covariance sigma^2 I + bias_sigma^2 11^T; null: independent samples",
    )


class EphemerisOptions(_Strict):
    """Use each image's ``ephemeris`` (state vectors) for its line-0 state (seed 001 section 5).

    The state vectors are interpolated to ``first_line_time_s`` (Hermite with positions and
    velocities over the ``nodes`` nearest samples, :mod:`solver.observations.ephemeris`) and replace the
    image's ``approx_state`` position and velocity. With ``sigma_position_m`` (and optionally
    ``sigma_velocity_m_s``) they also enter the adjustment as weighted observations of the
    model's state: state = ephemeris value + correction (seed 001 eqs 38-43). Without sigmas the
    interpolated state only initialises the models.
    """

    sigma_position_m: SigmaM | None = None
    sigma_velocity_m_s: _num(ge=1e-9, le=1e5) | None = None
    nodes: _int(ge=2, le=8) = Field(default=4, description="samples used around the epoch")

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

    estimate: list[str] = Field(min_length=1, max_length=MAX_IOP)
    cameras: list[str] | None = None
    master_chip: dict[str, str] = Field(default_factory=dict)
    sigmas: dict[str, _num(ge=1e-20, le=1e6) | None] = Field(default_factory=dict)
    exclude: list[str] = Field(
        default_factory=list, description="'<camera id>/<parameter>' left out of the estimation (held)"
    )
    significance_analysis: Bool = False
    significance_threshold: _num(gt=0, le=1e3) = Field(
        default=1.0,
        description="drop while |estimate| < threshold * sigma (seed 001: 1; 3 removes the spurious "
        "chip bendings measured in docs/experiments.md, seed001 section)",
    )

    @field_validator("estimate", "cameras", "exclude")
    @classmethod
    def _distinct(cls, v: list[str] | None) -> list[str] | None:
        return v if v is None else _unique(v, "name")


class BlunderDetection(_Strict):
    """Data snooping (Baarda's w-test with sigma0 a priori known, Pope's tau test with sigma0
    estimated), reliability and the removal of rejected observations (docs/quality.md)."""

    alpha0: _num(gt=0, lt=0.5) = Field(default=0.001, description="significance level of each test")
    beta: _num(gt=0.05, lt=1) = Field(default=0.8, description="power for the minimal detectable biases")
    action: Literal["remove", "report"] = Field(
        default="remove",
        description="remove the worst rejected observation (group) and re-adjust until no test "
        "fails (remove), or only test and report (report)",
    )
    max_rejections: _int(ge=0, le=1_000_000) | None = Field(
        default=None,
        description="at most this many removals; null: a limit relative to the observations "
        "(5% of the tests, at least 20; quality.blunder_detection.max_rejections says which)",
    )
    variance: Literal["apriori", "estimated"] = Field(
        default="apriori",
        description="apriori: Baarda's data snooping with sigma0_apriori taken as known; "
        "estimated: Pope's tau test with the a-posteriori sigma0",
    )
    robust_start: Literal["none", "huber", "cauchy"] = Field(
        default="huber",
        description="first adjust with this loss (scale: loss_scale) and remove the worst failed "
        "test of each point on the robust residuals, then snoop by least squares",
    )
    reinstate: Bool = Field(
        default=True,
        description="after the removals, test every removed observation against the final "
        "solution (as an observation outside the adjustment) and put back those that pass",
    )
    separability: _num(gt=0.5, le=1) = Field(
        default=0.99,
        description="tests correlated at least this much with the rejected one (for its estimated "
        "error) cannot be told apart from it: they are reported as one non-identifiable group",
    )
    external_points: bool = Field(
        default=False,
        description="external reliability on points: per tie and check point, the largest effect of "
        "any observation's minimal detectable bias and which observation (quality.reliability."
        "external_points; costs about one more covariance pass, docs/quality.md)",
    )


class QualityWarnings(_Strict):
    """Limits beyond which a parameter of the solution is named in ``quality.warnings``
    (docs/models.md, quality control)."""

    attitude_sigma_deg: _num(gt=0, le=360) = Field(
        default=0.1,
        description="an attitude term whose sigma, as an angle over half the image, exceeds this (deg)",
    )
    correlation: _num(gt=0, le=1) = Field(
        default=0.99, description="two orientation parameters correlated beyond this in magnitude"
    )


class Parsimony(_Strict):
    """Significance analysis of the platform terms (docs/models.md, quality control): adjust,
    take the platform term (attitude rate, polynomial term of order >= 1) with the smallest
    |estimate| / sigma while it is below ``threshold``, hold it at zero and re-adjust if the
    test of that constraint passes at ``alpha``; repeat. Every step is reported in
    ``quality.parsimony``."""

    threshold: _num(gt=0, le=1e3) = Field(default=2.0, description="candidate while |estimate| < threshold * sigma")
    alpha: _num(gt=0, lt=0.5) = Field(default=0.05, description="level of the F test of the constraint")
    max_steps: _int(ge=1, le=100) = Field(default=20, description="at most this many terms dropped")


class PreanalysisOptions(_Strict):
    """Pre-analysis (``pba preanalysis``): how the planned points will be measured."""

    sigma_px: SigmaPx = Field(default=0.5, description="image measurement sigma of every planned observation, pixels")
    line_points: _int(ge=2, le=100) = Field(
        default=8, description="image points planned per control line and image (evenly spaced between its endpoints)"
    )


class DatumOptions(_Strict):
    """The datum analysis before the solve (docs/datum.md): which directions of the block as a
    whole (a common shift, tilt, rotation or scale of the tie points) the job leaves undetermined."""

    undetermined: Literal["refuse", "report"] = Field(
        default="refuse",
        description="a job whose datum has an undetermined direction is refused before the solve, with the "
        "direction named and the remedies (refuse), or adjusted and the report says it (report)",
    )
    max_sigma_m: _num(gt=0, le=1e7) = Field(
        default=100.0,
        description="a direction whose predicted sigma (metres of tie-point motion) exceeds this is undetermined",
    )


# The solver reads these as four objects (how to solve, which blocks, which statistics, which
# procedures): solver.schema.settings.JobSettings.from_options; the wire format stays this one.
class SolverOptions(_Strict):
    """How to solve and what to report."""

    max_iterations: _int(ge=1, le=1000) = 50
    function_tolerance: _num(gt=0, le=1) = 1e-10
    parameter_tolerance: _num(gt=0, le=1) = 1e-10
    control: Literal["weighted", "fixed"] = "weighted"
    sigma0_apriori: _num(ge=1e-6, le=1e6) = 1.0
    alpha: _num(gt=0, lt=0.5) = 0.05
    correlation_threshold: _num(gt=0, le=1) = 0.75
    covariance: Bool = True
    loss: Literal["none", "huber", "cauchy"] = "none"
    loss_scale: _num(ge=1e-6, le=1e6) = 3.0
    kernel: Literal["auto", "python"] = Field(
        default="auto",
        deprecated=True,
        description="deprecated and ignored: the solver chooses its residual kernels itself; still "
        "accepted so that existing job documents stay valid, to be removed in the next schema version",
    )
    self_calibration: SelfCalibration | None = None
    models: list[str] = Field(
        default_factory=list,
        max_length=MAX_COMPARED_MODELS,
        description="model comparison: adjust the same observations with each of these models "
        f"(distinct, at most {MAX_COMPARED_MODELS})",
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
    blunder_detection: BlunderDetection | None = Field(
        default=None,
        description="quality control: data snooping, reliability and removal of blunders "
        "({} for the defaults; docs/quality.md)",
    )
    leave_one_out: Bool = Field(
        default=True,
        description="withhold each control point in turn (from the solution, no re-adjustment) and "
        "report its discrepancy and predicted sigma (quality.leave_one_out)",
    )
    quality_warnings: QualityWarnings = Field(
        default_factory=QualityWarnings,
        description="limits of the warnings on implausible sigmas and high correlations (quality.warnings)",
    )
    preanalysis: PreanalysisOptions | None = Field(
        default=None, description="pre-analysis only: the planned measurement precision (default 0.5 px)"
    )
    parsimony: Parsimony | None = Field(
        default=None,
        description="drop the platform terms that are not significant, one at a time with a test of "
        "the constraint (quality.parsimony); null: off",
    )
    control_check: Literal["refuse", "warn"] = Field(
        default="refuse",
        description="control points whose measurements lie far from where the orientation the job starts from "
        "projects them (far outside the image, or beyond 20 times the stated uncertainty of a weighted orbit and "
        "attitude): refuse the job naming them (refuse), or adjust anyway and name them in the report's warnings (warn)",
    )
    datum: DatumOptions = Field(
        default_factory=DatumOptions,
        description="the datum analysis before the solve: what defines the datum, and refusing (or reporting) "
        "a job that leaves a direction of it undetermined (quality.datum)",
    )
    weak_control: Literal["act", "warn"] = Field(
        default="act",
        description="when the control does not determine an attitude term (its sigma over half the image beyond "
        "quality_warnings.attitude_sigma_deg): run the significance analysis of the platform terms and report it "
        "in quality.weak_control (act), or only warn (warn)",
    )


class Job(_Strict):
    """A complete adjustment job."""

    schema_version: Literal["1.0"] = SCHEMA_VERSION
    name: str = Field(default="job", max_length=200)
    crs: str = Field(
        default="EPSG:4326", min_length=1, max_length=4096, description="default CRS of ground coordinates"
    )
    cameras: list[Camera] = Field(default_factory=list, description="empty when every image is an RPC image")
    images: list[Image] = Field(min_length=1)
    points: list[GroundPoint] = Field(default_factory=list)
    observations: list[ImageObservation] = Field(default_factory=list)
    lines: list[GroundLine] = Field(
        default_factory=list, description="straight lines (control or check) and their image observations"
    )
    dem: DemHeights | None = Field(default=None, description="DEM heights as observations of the tie points")
    options: SolverOptions = Field(default_factory=SolverOptions)

    @model_validator(mode="before")
    @classmethod
    def _image_camera_refs(cls, data: Any) -> Any:
        """An image may name a library camera (or sensor preset) in place:
        ``"camera": {"ref": {"name": "prism-nadir"[, "version": 1]}}``. It becomes the
        ``cameras`` entry ``{"id": "prism-nadir"[@v1], "ref": {...}}`` (added once, however
        many images name it) and the image names that id; the server resolves the ref."""
        if not isinstance(data, dict) or not isinstance(data.get("images"), list):
            return data
        if not any(isinstance(im, dict) and isinstance(im.get("camera"), dict) for im in data["images"]):
            return data
        cameras = list(data.get("cameras") or [])
        by_id = {c.get("id"): c for c in cameras if isinstance(c, dict)}
        images = []
        for k, im in enumerate(data["images"]):
            if isinstance(im, dict) and isinstance(im.get("camera"), dict):
                ref = im["camera"].get("ref")
                if set(im["camera"]) != {"ref"} or not isinstance(ref, dict) or not isinstance(ref.get("name"), str):
                    raise ValueError(
                        f"images[{k}].camera is a camera id or {{\"ref\": {{\"name\": ..., \"version\": ...}}}}"
                    )
                cid = ref["name"] + (f"@v{ref['version']}" if ref.get("version") is not None else "")
                entry = {"id": cid, "ref": dict(ref)}
                if cid not in by_id:
                    cameras.append(entry)
                    by_id[cid] = entry
                elif by_id[cid] != entry:
                    raise ValueError(f"images[{k}].camera refers to {cid!r}, which cameras[] defines otherwise")
                im = {**im, "camera": cid}
            images.append(im)
        return {**data, "images": images, "cameras": cameras}


def load_job(data: dict[str, Any] | str | bytes) -> Job:
    """Parse a job from a dict or JSON text (raises pydantic.ValidationError)."""
    if isinstance(data, (str, bytes)):
        return Job.model_validate_json(data)
    return Job.model_validate(data)
