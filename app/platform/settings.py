"""Service settings, read from the environment with the ``VANTAGE_`` prefix."""

from __future__ import annotations

import ipaddress
import os
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity, where the system reports one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


class Settings(BaseSettings):
    """Everything the service can be told from outside.

    Defaults are for a single machine: an SQLite file in ``data_dir`` and frames stored beside it.
    """

    model_config = SettingsConfigDict(env_prefix="VANTAGE_", env_file=".env", extra="ignore")

    env: Literal["development", "test", "production"] = Field(
        default="development",
        description="development, test or production; production refuses admin and metrics "
        "tokens shorter than 24 characters.",
    )
    data_dir: Path = Field(default=Path("data"), description="Database file, frames, admin token.")
    database_url: str | None = Field(
        default=None, description="SQLAlchemy URL; default: SQLite file in data_dir."
    )
    admin_token: SecretStr | None = Field(
        default=None, description="Operator token; generated and saved in data_dir when unset."
    )
    metrics_token: SecretStr | None = Field(
        default=None,
        description="A token that may read /metrics only (a Prometheus scraper's); the admin "
        "token may too.",
    )
    max_body_bytes: int = Field(default=10 * 1024 * 1024, gt=0, description="Request body cap [B].")
    max_pixels: int = Field(
        default=50_000_000,
        gt=0,
        description="Image size cap [px]: larger images are refused before they are decoded "
        "(a 48 MP phone photo is 48 000 000). Set it in the environment: OpenCV reads it once, "
        "at start, as its own cap.",
    )
    frame_retention_days: float = Field(
        default=30.0, gt=0, description="Keep frames this long [d]."
    )
    history_retention_days: float | None = Field(
        default=None,
        gt=0,
        description="Keep frames' rows (verdicts, readings, trends) this long [d], their images"
        " only for frame_retention_days; default: the rows go with their images.",
    )
    map_tiles: str = Field(
        default="https://tile.openstreetmap.org/{z}/{x}/{y}.png",
        description="Base map tiles of the /map page (a Leaflet URL template, {z}/{x}/{y}); "
        "its bands, cameras and labels draw without them (no network).",
    )
    map_attribution: str = Field(
        default='&copy; <a href="https://www.openstreetmap.org/copyright">OpenStreetMap</a> '
        "contributors",
        description="The tiles' attribution, shown on the map (HTML).",
    )
    cors_origins: list[str] = Field(
        default=["*"],
        description="Origins whose pages may read the public GET /air/... endpoints (a "
        "dashboard served elsewhere); [] for none. JSON in the environment: "
        '["https://dashboard.example.org"].',
    )
    frame_ancestors: list[str] = Field(
        default=[],
        description="Origins that may show the pages in a frame (CSP frame-ancestors), e.g. "
        'a signage system: ["https://signage.example.org"]; [] for none.',
    )
    source_allowed_networks: Annotated[list[str], NoDecode] = Field(
        default=[],
        description="Networks (CIDRs, comma-separated) that camera sources may reach although "
        "the rule refuses them: loopback, link-local, unspecified, multicast and reserved "
        "addresses; e.g. 127.0.0.0/8 for a relay on the same machine. Private LANs and public "
        "addresses are allowed without this.",
    )
    public_requests_per_minute: int = Field(
        default=300,
        ge=0,
        description="Requests without a token one client (address) may make per minute to the "
        "public endpoints, per process; more → 429 with Retry-After. 0: no limit.",
    )
    public_work_per_minute: int = Field(
        default=20,
        ge=0,
        description="Of those, computations (isopleth maps, aggregates of the readings) one "
        "client may ask for per minute, per process; a map served from the cache does not "
        "count. 0: no limit.",
    )
    public_work_queue: int = Field(
        default=8,
        ge=1,
        description="Public computations that may wait for a turn per process; one more → 503 "
        "with Retry-After, at once.",
    )
    isopleth_cache_seconds: float = Field(
        default=30.0,
        ge=0,
        description="Serve an isopleth map (GeoJSON or PNG) computed this recently for the same "
        "request instead of computing it again [s]; 0: compute every time.",
    )
    retention_sweep_seconds: float = Field(
        default=3600.0, gt=0, description="How often old frames are swept [s]."
    )
    orphan_min_age_seconds: float = Field(
        default=600.0,
        ge=0,
        description="At start, delete frame files and packs no row refers to once older "
        "than this [s] (younger ones may belong to another process's upload in flight).",
    )
    store_frames: bool = Field(default=True, description="Keep the JPEG bytes.")
    keep_free_disk_mb: float = Field(
        default=256.0,
        ge=0,
        description="Space kept free on the frame store's disk (a directory) for the database: "
        "below it, uploads are refused (503 disk_full) and /health says the store is full. "
        "0: frames may fill the disk.",
    )
    frame_store: Literal["disk", "s3"] = Field(
        default="disk",
        description="Where frames go: 'disk' (data_dir/frames, a shared volume for several "
        "processes) or 's3' (a bucket of an S3-compatible store, for several machines).",
    )
    s3_bucket: str | None = Field(default=None, description="The bucket (frame_store=s3).")
    s3_prefix: str = Field(default="", description="Key prefix inside the bucket, e.g. 'city/'.")
    s3_endpoint_url: str | None = Field(
        default=None, description="An S3-compatible store's URL (MinIO, Ceph …); default: AWS."
    )
    s3_region: str | None = Field(default=None, description="The bucket's region.")
    frame_store_timeout_seconds: float = Field(
        default=10.0,
        gt=0,
        le=300,
        description="How long /health and the image endpoints wait for the frame store before "
        "answering 503, and the start-up before serving without it (a network mount whose "
        "server is gone blocks every call into it).",
    )
    fsync_frames: bool = Field(
        default=False,
        description="fsync each stored frame: survives power loss, not only a process crash.",
    )
    ingest_threads: int = Field(
        default=0,
        ge=0,
        description="Frames decoded and stored at once per process. 0: as many as the CPUs the "
        "process may use (at least 2) with the disk store (more threads than cores only "
        "contend for them and for the GIL), 32 with the S3 store (each upload then waits on "
        "the network).",
    )
    image_threads: int = Field(
        default=0,
        ge=0,
        description="Image-processing requests (outlines, laser, checkerboards, training "
        "uploads) worked on at once per process; the others wait their turn. Each holds its "
        "images' pixels, so this bounds memory too. 0: the CPUs the process may use.",
    )
    public_work_threads: int = Field(
        default=1,
        ge=1,
        description="Public computations (isopleth maps, hourly and daily aggregates of the "
        "readings) worked on at once per process; the others wait their turn. Anyone may ask "
        "for them and each can take seconds of CPU and database: they may not crowd out the "
        "cameras' uploads.",
    )
    warm_up_triangulation: bool = Field(
        default=False,
        description="Compile the calibrated-rig triangulation loop (numba) at start, before "
        "serving (10–12 s the first time, a few seconds from its cache), instead of on the first "
        "request that needs it. It costs ~100 MB a process: for robot cells.",
    )
    camera_cache_seconds: float = Field(
        default=10.0,
        ge=0,
        le=3600,
        description="How long a process keeps a camera's token and configuration once seen, "
        "so that a frame costs no lookup: a change made through another process (a new "
        "region, a new token) reaches this one within that time. 0: look up every frame.",
    )
    database_pool_size: int = Field(
        default=10,
        ge=1,
        le=1000,
        description="PostgreSQL connections a process keeps open (its frame writer keeps one).",
    )
    database_statement_timeout_seconds: float = Field(
        default=30.0,
        ge=0,
        le=86400,
        description="How long a statement may run or wait for a lock on PostgreSQL "
        "(statement_timeout); then the request gets 503 database_unavailable. 0: no bound.",
    )
    database_max_overflow: int = Field(
        default=20,
        ge=0,
        le=1000,
        description="PostgreSQL connections a process opens beyond the pool under load: each "
        "process may hold pool size + overflow, which over all processes must stay under the "
        "server's max_connections.",
    )
    shutdown_grace_seconds: float = Field(
        default=20.0,
        gt=0,
        le=3600,
        description="How long a stop (SIGTERM) waits for requests under way before cancelling "
        "them (uvicorn's --timeout-graceful-shutdown); under the orchestrator's own grace "
        "before it kills (Kubernetes: 30 s).",
    )
    upload_timeout_seconds: float = Field(
        default=30.0,
        gt=0,
        le=600,
        description="How long an upload may wait to be measured and stored (a database or "
        "disk that hangs, a process overloaded): then 503 with Retry-After, and a frame not "
        "yet being written is dropped, not stored later behind the camera's back.",
    )
    rate_limit_per_minute: int = Field(
        default=600,
        ge=0,
        description="Frames a camera may post per clock minute, over all processes (the "
        "budget is reserved in the database in blocks of 1/20); more → 429 with Retry-After. "
        "0: no limit.",
    )
    cleaning_debounce: int = Field(
        default=3, ge=1, description="Consecutive dirty verdicts that open a cleaning task."
    )
    lease_seconds: float = Field(default=600.0, gt=0, description="A claimed task's lease [s].")
    max_upload_bytes: int = Field(
        default=200 * 1024 * 1024, gt=0, description="Cap for multi-image training uploads [B]."
    )
    alert_webhook_url: str | None = Field(
        default=None, description="POST each air-quality alert here (JSON), with retries."
    )
    alert_webhook_secret: SecretStr | None = Field(
        default=None,
        description="Sign each alert's POST with this Standard Webhooks secret ('whsec_' and the"
        " base64 of 24–64 random bytes): the receiver checks the webhook-signature header.",
    )
    pull_sources: bool = Field(
        default=True,
        description="Pull the frames of cameras registered with a source (RTSP, MJPEG or "
        "snapshot URL); false: this process pulls none (others may).",
    )
    pull_threads: int = Field(
        default=8,
        ge=1,
        le=256,
        description="Sources this process pulls at once (each waits on its camera's network).",
    )
    pull_timeout_seconds: float = Field(
        default=10.0,
        gt=0,
        le=300,
        description="Longest wait for a source to open or to give a frame (FFmpeg's own open "
        "and read timeouts, and the snapshot's HTTP timeout) [s].",
    )
    alert_poll_seconds: float = Field(default=5.0, gt=0, description="Webhook sweep interval [s].")
    air_recalibrate_hours: float | None = Field(
        default=None,
        gt=0,
        description="Recalibrate each located sky camera from the reference stations within "
        "air_station_km of it every … hours (rolling calibration), and flag a camera whose "
        "readings have drifted from its station's; off by default.",
    )
    air_recalibrate_days: float = Field(
        default=30.0, gt=0, description="A rolling calibration pairs the frames of the last … days."
    )
    air_station_km: float = Field(
        default=10.0, gt=0, le=1000, description="Stations this near a camera calibrate it [km]."
    )
    alert_retry_hours: float = Field(
        default=24.0, gt=0, description="Retry an undelivered alert this long after it was raised."
    )
    log_level: str = Field(
        default="INFO", description="Python logging level of the service's and uvicorn's lines."
    )
    log_json: bool = Field(
        default=True, description="Log lines as JSON objects (false: plain text, for a terminal)."
    )

    @property
    def effective_image_threads(self) -> int:
        return self.image_threads or usable_cpus()

    @property
    def effective_ingest_threads(self) -> int:
        if self.ingest_threads:
            return self.ingest_threads
        if self.frame_store == "s3":
            return 32
        # one a core: with more, the threads' hand-offs of the GIL cost more than the extra
        # decoding in parallel gains
        return max(2, usable_cpus())

    @field_validator("source_allowed_networks", mode="before")
    @classmethod
    def _networks(cls, value: object) -> object:
        """Comma-separated CIDRs from the environment, or a list; each must parse."""
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if isinstance(value, list):
            for v in value:
                try:
                    ipaddress.ip_network(str(v), strict=False)
                except ValueError:
                    raise ValueError(f"{v!r} is not a network (CIDR, e.g. 127.0.0.0/8)") from None
        return value

    @model_validator(mode="after")
    def _refuse_unsafe(self) -> Settings:
        for name, token in (("ADMIN", self.admin_token), ("METRICS", self.metrics_token)):
            if (
                self.env == "production"
                and token is not None
                and len(token.get_secret_value()) < 24
            ):
                raise ValueError(
                    f"VANTAGE_{name}_TOKEN must be at least 24 characters in production"
                )
        if (
            self.history_retention_days is not None
            and self.history_retention_days < self.frame_retention_days
        ):
            raise ValueError(
                "VANTAGE_HISTORY_RETENTION_DAYS must be at least VANTAGE_FRAME_RETENTION_DAYS:"
                " a frame's image is kept only with its row"
            )
        if self.alert_webhook_url is not None:
            from app.platform.webhooks import check_url

            try:
                check_url(self.alert_webhook_url)
            except ValueError as exc:
                raise ValueError(f"VANTAGE_ALERT_WEBHOOK_URL: {exc}") from None
        if self.alert_webhook_secret is not None:
            from app.platform.webhooks import signing_key

            try:
                signing_key(self.alert_webhook_secret.get_secret_value())
            except ValueError as exc:
                raise ValueError(f"VANTAGE_ALERT_WEBHOOK_SECRET: {exc}") from None
        if self.frame_store == "s3" and not self.s3_bucket:
            raise ValueError("VANTAGE_FRAME_STORE=s3 needs VANTAGE_S3_BUCKET")
        if self.frame_store == "s3" and self.admin_token is None:
            # a generated token is kept in the data directory, which machines sharing a bucket
            # do not share: each would make its own
            raise ValueError("VANTAGE_FRAME_STORE=s3 needs VANTAGE_ADMIN_TOKEN set")
        return self

    @property
    def effective_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'vantage.db').resolve()}"


@lru_cache
def get_settings() -> Settings:
    return Settings()
