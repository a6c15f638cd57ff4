"""Public request and response models (OGC API - Processes 1.0 names where it defines them).

The job document itself is :class:`solver.schema.job.Job`, defined once and used here unchanged.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from service.states import JobStatus
from solver.matching.features import MatchSettings
from solver.schema.job import MAX_COMPARED_MODELS, Camera, IopCovariance, Job

MAX_MATCH_RASTERS = 16  # rasters of one match request
_MATCH = MatchSettings()


class ProblemEntry(BaseModel):
    """One problem of a request, located by a JSON pointer into the request body."""

    model_config = ConfigDict(extra="allow")

    pointer: str
    code: str
    message: str


class Problem(BaseModel):
    """An RFC 7807 problem document (``application/problem+json``)."""

    model_config = ConfigDict(extra="allow")

    type: str
    title: str
    status: int
    detail: str
    instance: str | None = None
    errors: list[ProblemEntry] | None = None


class Link(BaseModel):
    """A web link (OGC link.yaml)."""

    href: str
    rel: str
    type: str | None = None
    title: str | None = None


class LandingPage(BaseModel):
    """``GET /``."""

    title: str
    description: str
    links: list[Link]


class Conformance(BaseModel):
    """``GET /conformance``."""

    conformsTo: list[str]


class ProcessSummary(BaseModel):
    """One process in ``GET /processes``."""

    id: str
    title: str
    description: str
    version: str
    jobControlOptions: list[Literal["sync-execute", "async-execute", "dismiss"]]
    outputTransmission: list[Literal["value", "reference"]]
    links: list[Link] = Field(default_factory=list)


class ProcessList(BaseModel):
    """``GET /processes``."""

    processes: list[ProcessSummary]
    links: list[Link]


class InputDescription(BaseModel):
    """An input of a process (OGC inputDescription.yaml)."""

    model_config = ConfigDict(populate_by_name=True)

    title: str
    description: str
    minOccurs: int = 1
    maxOccurs: int = 1
    schema_: dict[str, Any] = Field(alias="schema")


class OutputDescription(BaseModel):
    """An output of a process (OGC outputDescription.yaml)."""

    model_config = ConfigDict(populate_by_name=True)

    title: str
    description: str
    schema_: dict[str, Any] = Field(alias="schema")


class ProcessDescription(ProcessSummary):
    """``GET /processes/{processId}``."""

    inputs: dict[str, InputDescription]
    outputs: dict[str, OutputDescription]


class MatchRaster(BaseModel):
    """One raster of the match process: a file under the server's image root (``path``, inside
    the caller's subfolder) or an upload (``value``: the file's bytes in base64)."""

    model_config = ConfigDict(extra="forbid")

    id: str = Field(min_length=1, max_length=64, description="the job's image id")
    path: str | None = Field(
        default=None,
        min_length=1,
        max_length=1024,
        description="a raster under PBA_IMAGE_ROOT, relative to the caller's subfolder",
    )
    value: str | None = Field(default=None, min_length=1, description="an uploaded raster, base64")
    mediaType: str | None = Field(default=None, max_length=100, description="of an upload (ignored)")

    @model_validator(mode="after")
    def _one_source(self) -> "MatchRaster":
        if (self.path is None) == (self.value is None):
            raise ValueError("give either path (a raster on the server) or value (an upload)")
        return self


class MatchSettingsInput(BaseModel):
    """The match process's settings (those of ``pba match``, docs/matching.md)."""

    model_config = ConfigDict(extra="forbid")

    grid: int = Field(_MATCH.grid, ge=1, le=200, description="tiles / thinning cells per image side")
    per_cell: int = Field(_MATCH.per_cell, ge=1, le=100, description="tie points kept per cell of each image")
    search_px: float = Field(_MATCH.search_px, gt=0, le=10_000, description="half-width of the search band, px")
    min_ncc: float = Field(_MATCH.min_ncc, gt=0, lt=1, description="lowest accepted correlation peak")


class ExecuteInputs(BaseModel):
    """Inputs of the processes: the job document; for a comparison the model names; for the
    match process the rasters, the terrain height range and the settings."""

    model_config = ConfigDict(extra="forbid")

    job: Job
    models: list[str] | None = Field(
        default=None,
        max_length=MAX_COMPARED_MODELS,
        description="model-comparison only: platform models to compare (default: the job's "
        "options.models)",
    )
    images: list[MatchRaster] | None = Field(
        default=None,
        min_length=2,
        max_length=MAX_MATCH_RASTERS,
        description="match only: the rasters of the job's images to match (at least two)",
    )
    heights_m: tuple[float, float] | None = Field(
        default=None,
        description="match only: the terrain's ellipsoidal height range MIN, MAX in metres "
        "(default: the job's points +- 100 m, or the RPCs' range)",
    )
    match: MatchSettingsInput | None = Field(default=None, description="match only: settings")


class Execute(BaseModel):
    """Body of ``POST /processes/{processId}/execution`` (OGC execute.yaml)."""

    model_config = ConfigDict(extra="forbid")

    inputs: ExecuteInputs
    outputs: dict[str, Any] | None = Field(default=None, description="accepted and ignored")
    response: Literal["raw", "document"] = Field(
        default="raw",
        description="synchronous answer: the report itself (raw) or {'report': ...} (document)",
    )
    mode: Literal["sync", "async", "auto"] | None = Field(
        default=None, description="pre-1.0 alternative to the Prefer header"
    )
    subscriber: dict[str, Any] | None = Field(default=None, description="not supported; ignored")


class StatusInfo(BaseModel):
    """The status of a job (OGC statusInfo.yaml) plus the job's ``problems`` when it failed."""

    jobID: str
    processID: str
    type: Literal["process"] = "process"
    status: JobStatus
    message: str
    created: datetime
    started: datetime | None = None
    finished: datetime | None = None
    updated: datetime
    progress: int = Field(ge=0, le=100)
    problems: list[dict[str, Any]] | None = None
    queuePosition: int | None = Field(
        default=None,
        ge=1,
        description="an accepted job's place among the waiting jobs in the fair-share order "
        "(1: the next free worker takes it); on a job's own status document only",
    )
    estimatedStart: datetime | None = Field(
        default=None,
        description="an accepted job's estimated start (UTC), from the mean duration of recent "
        "solves and the workers alive; absent without history or workers",
    )
    links: list[Link]


class JobList(BaseModel):
    """``GET /jobs``."""

    jobs: list[StatusInfo]
    numberMatched: int
    links: list[Link]


class ValidationReport(BaseModel):
    """``POST /jobs/validate``: the solver's dry-run summary of a valid job."""

    model_config = ConfigDict(extra="allow")

    valid: bool
    n_observations: int | None = None
    n_unknowns: int | None = None
    dof: int | None = None
    images: list[dict[str, Any]] = Field(default_factory=list)
    problems: list[dict[str, Any]] = Field(default_factory=list)


class CameraDefinition(Camera):
    """A library camera: the job's camera fields (no ``ref``), ``id`` optional, plus the
    covariance of its interior orientation."""

    id: str = Field(default="camera", min_length=1, max_length=64)
    iop_covariance: IopCovariance | None = None

    @model_validator(mode="after")
    def _no_ref(self) -> "CameraDefinition":
        if self.ref is not None:
            raise ValueError("a library camera cannot itself refer to the library")
        return self


def _not_reserved(name: str) -> str:
    if name == "shared":
        raise ValueError("'shared' names the shared camera namespace; choose another name")
    return name


CameraName = Annotated[
    str,
    Field(min_length=1, max_length=128, pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]*$"),
    AfterValidator(_not_reserved),
]


class CameraCreate(BaseModel):
    """Body of ``POST /cameras``: a new version of a named camera in your own namespace, or
    (``shared: true``) in the shared namespace."""

    model_config = ConfigDict(extra="forbid")

    name: CameraName
    description: str = Field(default="", max_length=2000)
    definition: CameraDefinition
    shared: bool = Field(
        default=False,
        description="publish to the shared namespace (an admin, or the user who first "
        "published this shared name)",
    )


class CameraShare(BaseModel):
    """Body of ``POST /cameras/{name}/share``: publish one of your versions to the shared
    namespace (as its next version there)."""

    model_config = ConfigDict(extra="forbid", strict=True)  # "1" or true is not a version

    version: int | None = Field(
        default=None, ge=1, le=2_000_000_000, description="your version to share (latest if absent)"
    )


class CameraFromJob(BaseModel):
    """Body of ``POST /cameras/from-job``: save a camera estimated by a self-calibration job."""

    model_config = ConfigDict(extra="forbid")

    job_id: str = Field(min_length=1, max_length=64)
    camera: str = Field(min_length=1, max_length=64, description="camera id inside the job")
    name: CameraName
    description: str = Field(default="", max_length=2000)


class CameraPublic(BaseModel):
    """One version of a library camera."""

    name: str
    version: int
    shared: bool = Field(
        default=False, description="in the shared namespace (a job refers to it as shared/NAME)"
    )
    description: str
    definition: dict[str, Any]
    created: datetime
    source_job: str | None = None
    links: list[Link]


class CameraList(BaseModel):
    """``GET /cameras``."""

    cameras: list[CameraPublic]
    numberMatched: int
    links: list[Link]


class Health(BaseModel):
    """``/healthz`` and ``/readyz``."""

    status: Literal["ok", "unavailable"]
    checks: dict[str, str] = Field(default_factory=dict)


class UserAccount(BaseModel):
    """One user in the admin's accounting table: settings, current load and usage so far."""

    user: str = Field(description="user name")
    is_admin: bool
    weight: float = Field(description="fair-share weight (default 1)")
    max_running_jobs: int | None = Field(
        description="running cap while other users wait (null: PBA_MAX_RUNNING_PER_USER)"
    )
    max_queued_jobs: int | None = Field(description="null: the server's default")
    max_job_observations: int | None = Field(description="null: the server's default")
    waiting: int = Field(description="accepted jobs now")
    running: int = Field(description="running jobs now")
    jobs_successful: int = Field(description="finished runs, successful")
    jobs_failed: int = Field(description="finished runs, failed (the worker measured the run)")
    jobs_dismissed: int = Field(description="runs stopped by a cancellation")
    cpu_seconds: float = Field(description="CPU seconds of the solving processes, all runs")
    solve_seconds: float = Field(description="wall seconds of the solves, all runs")


class Accounting(BaseModel):
    """``GET /admin/users``: every user."""

    users: list[UserAccount]


class UserSettingsUpdate(BaseModel):
    """``PATCH /admin/users/{name}``: the fields given are changed, the others kept."""

    model_config = ConfigDict(extra="forbid", strict=True)  # "2" is not a weight

    weight: float | None = Field(default=None, gt=0, le=1000, description="fair-share weight")
    max_running_jobs: int | None = Field(
        default=None, ge=0, le=100000, description="running cap while others wait (0: none)"
    )
    max_queued_jobs: int | None = Field(default=None, gt=0, le=10_000_000)
    max_job_observations: int | None = Field(default=None, gt=0, le=1_000_000_000)


class RunningJob(BaseModel):
    """A running job on the admin page."""

    jobID: str
    user: str
    worker: str | None
    progress: int
    message: str
    started: datetime | None


class FailedJob(BaseModel):
    """A recent failure on the admin page."""

    jobID: str
    user: str
    finished: datetime | None
    message: str


class AdminOverview(BaseModel):
    """``GET /admin/overview``: what the admin page shows."""

    workers: int = Field(description="workers able to take jobs (this server's queue backend)")
    queue: str = Field(description="queue backend and its readiness")
    running: list[RunningJob]
    failures: list[FailedJob] = Field(description="the most recent failed jobs, newest first")
    users: list[UserAccount] = Field(description="per user: settings, load and accounting")
