"""Server settings: one pydantic-settings object read from ``PBA_*`` environment variables.

Every setting is documented by its ``description``, from which the documentation's settings
reference is generated (scripts/gen_reference.py; tests/test_docs.py checks every setting has
its entry). Units are in the names (``_s`` seconds, ``_bytes`` bytes).
"""

from __future__ import annotations

import ipaddress
from functools import cached_property
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1", "ip6-localhost"})


def is_loopback(host: str) -> bool:
    """True when ``host`` only accepts connections from this machine."""
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Settings(BaseSettings):
    """All server settings (environment prefix ``PBA_``)."""

    model_config = SettingsConfigDict(env_prefix="PBA_", extra="ignore")

    data_dir: Path = Field(Path("data"), description="directory of the SQLite file and logs")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL of the job store (default: SQLite in data_dir)"
    )
    host: str = Field("127.0.0.1", description="address the server binds to (pba serve --host)")
    port: int = Field(8000, ge=0, le=65535, description="port (pba serve --port)")
    public_url: str | None = Field(
        None, description="base URL used in links (default: taken from each request)"
    )
    trusted_hosts: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="comma-separated host names whose Host header links may use (without PBA_PUBLIC_URL)",
    )
    queue: Literal["local", "celery"] = Field("local", description="queue backend")
    workers: int = Field(2, ge=0, le=64, description="local worker processes (0: API only)")
    job_time_limit_s: float = Field(3600.0, gt=0, description="wall-clock limit of one solve")
    kill_grace_s: float = Field(
        10.0, gt=0, description="after the time limit, how long a worker may take to stop"
    )
    max_attempts: int = Field(
        2, ge=1, description="runs of a job interrupted by a server stop before it is failed"
    )
    sync_timeout_s: float = Field(
        60.0, ge=0, description="a synchronous execution waits this long, then answers 201"
    )
    sync_max_observations: int = Field(
        20000, ge=0, description="larger jobs always run asynchronously"
    )
    max_body_bytes: int = Field(64 * 1024 * 1024, gt=0, description="request body size limit")
    max_job_observations: int = Field(
        2_000_000, gt=0, description="default per-user limit on observations in one job"
    )
    image_root: Path | None = Field(
        None,
        description="match process: directory of the rasters already on the server, one subfolder "
        "per user name (a request names a raster by its path inside the caller's subfolder; none: "
        "uploads only)",
    )
    max_image_upload_bytes: int = Field(
        16 * 1024 * 1024,
        gt=0,
        description="match process: an uploaded raster (inputs.images[].value, decoded), at most",
    )
    max_upload_pixel_bytes: int = Field(
        256 * 1024 * 1024,
        gt=0,
        description="match process: an uploaded raster's band 1 decoded (width x height x bytes per pixel, "
        "from its header), at most; a small compressed file may claim a huge image",
    )
    max_raster_pixel_bytes: int = Field(
        16 * 1024**3,
        gt=0,
        description="match process: a raster under the image root, band 1 decoded (width x height x bytes per "
        "pixel, from its header), at most",
    )
    raster_check_processes: int = Field(
        3,
        ge=1,
        le=64,
        description="match process: processes of the API that read the rasters' headers at submission "
        "(outside the request threads)",
    )
    raster_check_timeout_s: float = Field(
        20.0,
        gt=0,
        le=3600,
        description="match process: a raster's header not read within this time at submission is refused "
        "(422 timeout) and its reading process replaced",
    )
    raster_checks_per_user: int = Field(
        2,
        ge=1,
        le=64,
        description="match process: header checks one user may have running at once; more are answered "
        "503 at once (Retry-After)",
    )
    compose_max_rows: int = Field(
        20_000,
        gt=0,
        description="POST /jobs/compose: lines of the uploads (once per file name in the spec), at most",
    )
    max_queued_jobs: int = Field(
        1000, gt=0, description="default per-user limit on accepted + running jobs"
    )
    require_api_keys: bool = Field(
        False, description="require keys even on 127.0.0.1 (always required on other binds)"
    )
    metrics_token: SecretStr | None = Field(
        None,
        min_length=16,
        description="bearer token that may read /metrics (besides an admin's key) when keys are required",
    )
    cors_origins: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="comma-separated origins allowed by CORS"
    )
    poll_interval_s: float = Field(0.2, gt=0, description="idle worker's store poll interval")
    progress_interval_s: float = Field(0.5, gt=0, description="progress writes, at most every")
    cancel_poll_interval_s: float = Field(0.2, gt=0, description="cancel flag reads, at most every")
    sse_interval_s: float = Field(0.5, gt=0, description="SSE stream's status poll interval")
    shutdown_grace_s: float = Field(10.0, ge=0, description="stop: wait for workers this long")
    # -- fair sharing (docs/how-to/lab-server.md "Fair sharing") -------------------------------------------
    max_running_per_user: int = Field(
        0,
        ge=0,
        description="while other users wait, a user's running jobs are capped at this (0: no cap)",
    )
    small_job_observations: int = Field(
        5000,
        ge=0,
        description="jobs with at most this many observations take the small-job lane",
    )
    small_job_workers: int = Field(
        1,
        ge=0,
        le=16,
        description="local workers beside PBA_WORKERS that only take small-lane jobs (none when PBA_WORKERS=0)",
    )
    # -- GIS requests (docs/server-limits.md "GIS requests") -----------------------------------
    gis_processes: int = Field(
        1,
        ge=1,
        le=16,
        description="GIS processes for RPC fits, GeoJSON and large transforms (beside the one for small transforms)",
    )
    gis_small_rows: int = Field(
        100,
        ge=0,
        le=10_000,
        description="transforms of at most this many rows go to the GIS process kept for small requests",
    )
    # -- distributed queue (PBA_QUEUE=celery; docs/how-to/scale-out.md) -----------------
    broker_url: str = Field(
        "redis://127.0.0.1:6379/0", description="Celery broker URL (PBA_QUEUE=celery)"
    )
    broker_key_prefix: str = Field(
        "", description="prefix of every Redis key the queue uses (several deployments, one Redis)"
    )
    broker_visibility_timeout_s: float = Field(
        300.0, gt=0, description="Redis gives an unacknowledged job message to another worker after"
    )
    celery_queue: str = Field("pba", min_length=1, description="Celery queue name of the jobs")
    celery_small_queue: str = Field(
        "pba-small",
        min_length=1,
        description="Celery queue of the small-job lane (read by pba worker --small-lane)",
    )
    worker_concurrency: int = Field(
        0, ge=0, le=256, description="solves at once per pba worker (0: one per CPU core)"
    )
    lease_s: float = Field(
        30.0, gt=0, description="a running job whose worker is silent this long is re-queued"
    )
    heartbeat_interval_s: float = Field(
        5.0, gt=0, description="a distributed worker renews its job's lease this often"
    )
    sweep_interval_s: float = Field(
        10.0, gt=0, description="how often expired leases are looked for (API and workers)"
    )
    # -- retention (docs/how-to/lab-server.md "Retention") ----------------------------------------------------
    job_retention_days: float = Field(
        0.0, ge=0, description="finished jobs older than this are deleted (0: keep forever)"
    )
    retention_interval_s: float = Field(
        3600.0, gt=0, description="how often the server deletes jobs past retention"
    )
    user_storage_quota_mb: float = Field(
        0.0,
        ge=0,
        description="per-user limit on stored job inputs and reports, MB (0: no limit)",
    )
    camera_max_bytes: int = Field(
        256_000, gt=0, description="a camera definition's JSON, at most (bytes)"
    )
    log_level: str = Field("INFO", description="logging level")
    log_format: Literal["json", "text"] = Field("json", description="log line format")
    docs_site_dir: Path | None = Field(
        None,
        description="built documentation site served under /docs-site (make docs; default: the "
        "site/ folder of a source checkout, when it has been built)",
    )

    @field_validator("cors_origins", "trusted_hosts", mode="before")
    @classmethod
    def _split_origins(cls, v: object) -> object:
        if isinstance(v, str):
            return [o.strip() for o in v.split(",") if o.strip()]
        return v

    @cached_property
    def resolved_database_url(self) -> str:
        """The store URL: ``database_url`` or ``sqlite:///<data_dir>/pba.sqlite3``."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'pba.sqlite3').resolve()}"

    @property
    def resolved_docs_site_dir(self) -> Path | None:
        """The built documentation site to serve, or None when there is none to serve."""
        folder = self.docs_site_dir or Path(__file__).resolve().parents[1] / "site"
        return folder if (folder / "index.html").is_file() else None

    @property
    def auth_required(self) -> bool:
        """API keys are required unless the server only listens on loopback (local mode)."""
        return self.require_api_keys or not is_loopback(self.host)
