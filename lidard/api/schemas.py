"""Request and response bodies of the REST API (pydantic, unknown fields rejected).

Request schemas are separate from response schemas (FastAPI full-stack template style) so that a
client can never set server-owned fields such as ``state`` or ``files``.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, field_validator, model_validator

from ..config import ScanDefaults
from ..errors import describe_validation
from ..instrument.types import PatternKind, ScanRequest
from ..outputs.registry import FORMATS as POINT_FORMATS, PointFormat

# the one list of point-file formats (lidard.outputs.registry)
FileFormat = PointFormat


def describe_errors(errors: list[dict[str, Any]]) -> str:
    """One line for a list of validation errors (pydantic's, or the daemon's 422 ``detail``):
    :func:`lidard.errors.describe_validation`, the one wording of the configuration's errors, the
    daemon's 422 bodies and lidarctl's own check of a request before it starts a bench."""
    return describe_validation(errors)


def check_scan_body(body: dict[str, Any]) -> ScanCreate:
    """Validate a POST /scans body exactly as the daemon will; ``ValueError`` carries
    :func:`describe_errors`' line."""
    from pydantic import ValidationError
    try:
        return ScanCreate.model_validate(body)
    except ValidationError as exc:
        raise ValueError(describe_errors([dict(e) for e in exc.errors()])) from None


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class _Out(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ScanCreate(_In):
    """POST /scans. ``rows``/``cols`` are [first, stop) ranges; ``pixels`` a list of [row, col]."""

    # Strict numbers: lax coercion would take ``true`` for 1.0 or "3" for 3 (found by schemathesis);
    # a body is what the client meant or a 422, never a guess.
    # pattern, averages, max_range_m: null (left out) takes the configuration's [scan] default
    # (config.ScanDefaults), filled in by :meth:`to_request`; a pixel list alone implies "pixels".
    pattern: PatternKind | None = None
    rows: tuple[StrictInt, StrictInt] | None = None
    cols: tuple[StrictInt, StrictInt] | None = None
    pixels: list[tuple[StrictInt, StrictInt]] | None = Field(default=None, min_length=1, max_length=1 << 20)
    averages: StrictInt | None = Field(default=None, ge=1, le=100)
    max_range_m: float | None = Field(default=None, gt=0, le=10_000, allow_inf_nan=False, strict=True)
    # the fastest radial speed to measure, m/s: sizes the digitizer's Doppler band; null: scan.max_speed_mps
    max_speed_mps: float | None = Field(default=None, gt=0, le=100, allow_inf_nan=False, strict=True)
    formats: list[FileFormat] = Field(default_factory=lambda: list[FileFormat](["ply"]), min_length=1,
                                      max_length=len(POINT_FORMATS))
    # laser phase-noise compensation from the monitor MZI (§2.3); null: the config's scan default
    phase_noise_compensation: Literal["auto", "on", "off"] | None = None
    # keep the digitizer's raw segments (Zarr under the data directory) for reprocessing
    record_raw: bool = Field(default=False, strict=True)

    @field_validator("rows", "cols")
    @classmethod
    def _range(cls, v: tuple[int, int] | None) -> tuple[int, int] | None:
        if v is not None and not (0 <= v[0] < v[1]):
            raise ValueError(f"must be a non-empty [first, stop) range with 0 <= first < stop, got {list(v)}")
        return v

    @field_validator("formats")
    @classmethod
    def _unique(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise ValueError(f"formats must not repeat, got {v}")
        return v

    @model_validator(mode="after")
    def _pixels_only_with_pixels(self) -> ScanCreate:
        if self.pattern == "pixels" and not self.pixels:
            raise ValueError("pattern 'pixels' needs a non-empty 'pixels' list")
        if self.pattern not in ("pixels", None) and self.pixels is not None:
            raise ValueError(f"'pixels' is only allowed with pattern 'pixels', not {self.pattern!r}")
        if self.record_raw and self.pattern == "adaptive":
            raise ValueError("record_raw: the adaptive pattern runs two acquisitions; record a raster, "
                             "serpentine, roi or pixels scan")
        return self

    def to_request(self, defaults: ScanDefaults | None = None) -> ScanRequest:
        """The instrument's request; fields left out take ``defaults`` (the configuration's [scan])."""
        d = defaults if defaults is not None else ScanDefaults()
        pattern = self.pattern or ("pixels" if self.pixels is not None else d.pattern)
        return ScanRequest(pattern=pattern, rows=self.rows, cols=self.cols,
                           pixels=None if self.pixels is None else tuple((p[0], p[1]) for p in self.pixels),
                           averages=d.averages if self.averages is None else self.averages,
                           max_range_m=d.max_range_m if self.max_range_m is None else self.max_range_m,
                           max_speed_mps=d.max_speed_mps if self.max_speed_mps is None else self.max_speed_mps,
                           formats=tuple(self.formats),
                           phase_noise_compensation=self.phase_noise_compensation,
                           record_raw=self.record_raw)


ScanState = Literal["queued", "running", "done", "failed", "cancelled", "interrupted"]


class Timing(_Out):
    created: float
    started: float | None = None
    finished: float | None = None
    hardware_time_s: float | None = None
    wall_time_s: float | None = None


class Counts(_Out):
    points: int
    pixels_scanned: int
    pixels_planned: int


class ScanOut(_Out):
    id: str
    state: ScanState
    stage: str
    progress: float
    partial: bool
    error: str | None = None
    request: dict[str, Any]
    timing: Timing
    counts: Counts
    formats: list[str]
    calibration_id: str | None = None
    raw_bytes: int | None = Field(None, description="bytes of the scan's raw capture on disk (record_raw); "
                                                    "null without one")
    reprocessed_from: str | None = Field(None, description="the scan whose raw capture this one reprocessed")
    range_calibration_id: str | None = Field(None, description="the range scale/zero calibration used")
    pointing_calibration_id: str | None = Field(None, description="the pointing calibration used")
    iq_calibration_id: str | None = Field(None, description="the I/Q imbalance calibration used (adc.iq)")
    calibrated: dict[str, bool] = Field(default_factory=dict, description=(
        "which calibrations the scan used: {range, pointing, linearization} and, with the I/Q receiver, iq; "
        "false is said, not hidden"))
    uncalibrated_reason: str | None = Field(None, description="why stored range/pointing/iq calibrations were "
                                                              "not used (made on another set-up); null when none was left out")

    @classmethod
    def from_record(cls, rec) -> ScanOut:
        return cls(id=rec.id, state=rec.state, stage=rec.stage, progress=rec.progress,
                   partial=rec.partial, error=rec.error, request=rec.request,
                   timing=Timing(created=rec.created, started=rec.started, finished=rec.finished,
                                 hardware_time_s=rec.hardware_time_s, wall_time_s=rec.wall_time_s),
                   counts=Counts(points=rec.points, pixels_scanned=rec.pixels_scanned,
                                 pixels_planned=rec.pixels_planned),
                   formats=sorted(rec.files), calibration_id=rec.calibration_id,
                   raw_bytes=getattr(rec, "raw_bytes", None), reprocessed_from=getattr(rec, "reprocessed_from", None),
                   range_calibration_id=rec.range_calibration_id, pointing_calibration_id=rec.pointing_calibration_id,
                   iq_calibration_id=rec.iq_calibration_id, calibrated=rec.calibrated,
                   uncalibrated_reason=getattr(rec, "uncalibrated_reason", None))


class ScanList(_Out):
    scans: list[ScanOut]
    queue_length: int
    running: str | None


class Health(_Out):
    status: Literal["ok", "degraded"]
    version: str
    simulated: bool
    worker_running: bool
    queue_length: int
    running_scan: str | None
    # the laser/HV controller's latched safety faults ([] none; None: unreadable); while any is
    # latched POST /scans answers 409 until `lidarctl faults ack` (POST /controller/acknowledge)
    latched_faults: list[str] | None = None
    interlock_closed: bool | None = None
    # the last scan's linearization health check (the sidecar's "linearization"): the chirp
    # error residual_hz against threshold_hz, whether it re-linearized and why. None before any scan
    linearization: dict[str, Any] | None = None


class DeviceStatus(_Out):
    """One instrument as GET /devices checks it: the link, and the device's own status reply both as
    data (``status``, ``identity_fields``: JSON objects, never Python reprs) and as a line for people
    (``state``, ``identity``)."""

    name: Literal["fpsa", "awg", "digitizer", "controller"]
    connected: bool
    reconnected: bool = Field(False, description="the link was reopened to answer this check")
    busy: bool = Field(False, description="in use by the running job: the entry is the last check")
    identity: str | None = Field(None, description="identification, one readable line")
    identity_fields: dict[str, Any] | None = Field(None, description="identification as data")
    state: str = Field(description="status reply as one readable line; 'unreachable' when the link is down")
    status: dict[str, Any] | None = Field(None, description="status reply as data (field -> value; enums "
                                                            "by name, flags and sets as lists of names)")
    faults: list[str] = Field(default_factory=list, description="fault names in the status reply, or "
                                                                "why the device is unreachable")


class DeviceList(_Out):
    devices: list[DeviceStatus]


class CalibrationOut(_Out):
    id: str | None
    laser: str
    temperature_c: float | None
    converged: bool
    created: float | None
    iterations: list[dict[str, float]]
    reduction: dict[str, float]
    fs_drive_hz: float
    drive_samples: int

    @classmethod
    def from_result(cls, cal) -> CalibrationOut:
        return cls(id=cal.meta.get("id"), laser=cal.laser, temperature_c=cal.temperature_c,
                   converged=bool(cal.converged), created=cal.meta.get("created"),
                   iterations=[{k: float(v) for k, v in it.items()} for it in cal.iterations],
                   reduction={k: float(v) for k, v in cal.reduction.items()},
                   fs_drive_hz=float(cal.fs_drive_hz), drive_samples=int(len(cal.drive_v)))


class SceneAccepted(_Out):
    name: str | None
    targets: int


class ControlAcquire(_In):
    """POST /control: who wants to steer the instrument (shown to everyone else)."""

    client: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9._@:+\- ]+$")


class ControlLease(_Out):
    """POST /control answer: ``lease`` goes in the ``X-Lidard-Lease`` header of mutating requests."""

    lease: str
    holder: str
    expires_at: float = Field(description="Unix time at which the lease lapses unless used again")
    ttl_s: float


class ControlStatus(_Out):
    """GET /control: who holds the lock (never the lease itself)."""

    held: bool
    holder: str | None = None
    expires_at: float | None = None
    expires_in_s: float | None = None
    ttl_s: float


# The DSP's names (lidard.dsp.ranging.estimators.EstimatorName, lidard.dsp.spectrum.window.WindowName), spelled out
# so that the API imports no numerical core; tests/lidard/raw/test_raw_cli.py keeps them equal.
EstimatorName = Literal["argmax", "parabolic", "jacobsen", "quinn2", "aboutanios", "newton"]
WindowName = Literal["rectangular", "hann", "blackmanharris"]


class ReprocessCreate(_In):
    """POST /scans/{id}/reprocess: overrides of the recorded DSP settings (null keeps the scan's)."""

    estimator: EstimatorName | None = None
    pfa: float | None = Field(default=None, gt=0, lt=0.1, allow_inf_nan=False, strict=True)
    window: WindowName | None = None
    phase_noise: Literal["on", "off"] | None = None
    formats: list[FileFormat] | None = Field(default=None, min_length=1, max_length=len(POINT_FORMATS),
                                               description="files of the new scan (default: the original's)")

    @field_validator("formats")
    @classmethod
    def _unique(cls, v: list[str] | None) -> list[str] | None:
        if v is not None and len(set(v)) != len(v):
            raise ValueError(f"formats must not repeat, got {v}")
        return v

    def settings(self):
        from ..raw import ReprocessSettings
        return ReprocessSettings(estimator=self.estimator, pfa=self.pfa, window=self.window,
                                 phase_noise=None if self.phase_noise is None else self.phase_noise == "on")
