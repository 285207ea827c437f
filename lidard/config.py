"""Typed configuration: pydantic models loaded from TOML, with environment overrides.

A configuration file (``config/sim.toml``, ``config/lab.toml``) names a scanner *profile*
(``config/profiles/<name>.toml``: the FPSA of dissertation §4.2 or §4.3 with its lenses, switch
dynamics and Table 4-4 losses), a *laser preset* (``config/profiles/lasers.toml``) and holds the chirp
(§4.4.1), detector/TIA/ADC and link-budget parameters (Table 2-2, §4.4.2), the device addresses and the
simulation settings.

Environment overrides: ``LIDARD__SECTION__KEY=value`` sets ``[section] key`` (value parsed as a TOML
literal when it parses, else taken as a string), e.g. ``LIDARD__ADC__BITS=12``.

Errors: every problem becomes one :class:`ConfigError` whose message names the file, the dotted key
and what is allowed. Loading is all-or-nothing: a :class:`Config` object exists only if everything
validated.
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .errors import ConfigError
from .physics.budget import LinkParams, optical_bandwidth_hz
from .physics.optics import FpsaOptics, bonded_rows_skip

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"
ENV_PREFIX = "LIDARD__"

PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# --------------------------------------------------------------------------------------------------
# Scanner profile (FPSA + lenses + switch dynamics + losses)
# --------------------------------------------------------------------------------------------------
class Lens(_Model):
    focal_m: PosFloat
    f_number: PosFloat
    description: str = ""

    @property
    def aperture_m(self) -> float:
        """Entrance pupil diameter f / N."""
        return self.focal_m / self.f_number


class SwitchTiming(_Model):
    """Optical response times of one switch type (10-90 % of the optical transmission)."""

    on_s: PosFloat
    off_s: PosFloat


class BondedRows(_Model):
    """Which row lines are wire-bonded: all, or all but one in every ``skip_every`` (§4.3.3)."""

    skip_every: int = Field(default=0, ge=0)
    skip_offset: int = Field(default=3, ge=0)


class FpsaLosses(_Model):
    """One-way optical losses of the beam scanner (Table 4-4), dB."""

    fiber_coupling_db: NonNegFloat
    waveguide_db: NonNegFloat
    row_switch_db: NonNegFloat
    col_switch_db: NonNegFloat
    antenna_db: NonNegFloat
    lens_db: NonNegFloat

    @property
    def total_db(self) -> float:
        return (self.fiber_coupling_db + self.waveguide_db + self.row_switch_db + self.col_switch_db
                + self.antenna_db + self.lens_db)


class Profile(_Model):
    name: str
    description: str = ""
    rows: int = Field(gt=0, le=1024)
    cols: int = Field(gt=0, le=1024)
    pitch_m: PosFloat
    emission_w_m: PosFloat
    bonded: BondedRows = BondedRows()
    actuation_v: PosFloat
    pull_in_v: PosFloat
    release_v: PosFloat
    #: 1-sigma switch-to-switch spread of pull-in and release (both move together), V (simulator)
    threshold_spread_v: NonNegFloat = 0.0
    #: HV583 output discharge time constant into an actuator: release delay rc*ln(V/V_release), s
    discharge_rc_s: NonNegFloat = 0.0
    row_switch: SwitchTiming
    col_switch: SwitchTiming
    lenses: dict[str, Lens]
    default_lens: str
    losses: FpsaLosses
    losses_improved: FpsaLosses | None = None

    @model_validator(mode="after")
    def _check(self) -> "Profile":
        if self.default_lens not in self.lenses:
            raise ValueError(f"default_lens {self.default_lens!r} is not one of the lenses {sorted(self.lenses)}")
        if not self.release_v < self.pull_in_v <= self.actuation_v:
            raise ValueError("need release_v < pull_in_v <= actuation_v (electrostatic pull-in hysteresis)")
        return self

    @property
    def bonded_rows(self) -> tuple[int, ...]:
        return bonded_rows_skip(self.rows, self.bonded.skip_every, self.bonded.skip_offset)

    def optics(self, lens: str | None = None, wavelength_m: float = 1.55e-6) -> FpsaOptics:
        name = lens or self.default_lens
        if name not in self.lenses:
            raise ConfigError(f"profile {self.name}: lens {name!r} unknown; allowed: {', '.join(sorted(self.lenses))}")
        return FpsaOptics(rows=self.rows, cols=self.cols, pitch_m=self.pitch_m,
                          emission_w_m=self.emission_w_m, focal_m=self.lenses[name].focal_m,
                          bonded_rows=self.bonded_rows, wavelength_m=wavelength_m)


# --------------------------------------------------------------------------------------------------
# Laser presets
# --------------------------------------------------------------------------------------------------
class ThermalTerm(_Model):
    """One thermal low-pass term of the DFB's FM response: gain (Hz per V of drive) and time constant."""

    gain_hz_per_v: float = Field(allow_inf_nan=False)
    tau_s: PosFloat


class LaserPreset(_Model):
    """A directly modulated DFB laser's FM response to the drive voltage u(t) and its noise.

    nu(t) - nu_0 = carrier_hz_per_v * g(u)(t) + sum_k (h_k * g(u))(t), with the static tuning
    nonlinearity g(u) = u + nonlin_a2 u^2 + nonlin_a3 u^3 and first-order low-pass thermal responses
    h_k of gain gain_hz_per_v and time constant tau_s. Thermal gains have the opposite sign to the
    carrier term (heating red-shifts a DFB), so the net static tuning is usually negative.
    Phase noise: Wiener process with linewidth = 1 / (pi coherence_time_s) (Table 2-2: 0.64 us).
    """

    description: str = ""
    wavelength_m: PosFloat = 1.55e-6
    carrier_hz_per_v: float = Field(allow_inf_nan=False)
    thermal: list[ThermalTerm] = []
    nonlin_a2: float = Field(default=0.0, allow_inf_nan=False)
    nonlin_a3: float = Field(default=0.0, allow_inf_nan=False)
    coherence_time_s: float = Field(default=0.64e-6, gt=0)  # inf = ideal laser
    rin_db_per_hz: float = Field(default=-150.0, le=0, allow_inf_nan=False)
    #: the laser's absolute maximum drive current: caps the controller's current limit
    #: (instrument.compose) and a devices.controller.laser_current_ma above it is refused at load
    max_current_ma: PosFloat = 200.0

    @property
    def linewidth_hz(self) -> float:
        return 0.0 if math.isinf(self.coherence_time_s) else 1.0 / (math.pi * self.coherence_time_s)

    @property
    def static_tuning_hz_per_v(self) -> float:
        return self.carrier_hz_per_v + sum(t.gain_hz_per_v for t in self.thermal)


# --------------------------------------------------------------------------------------------------
# The main configuration
# --------------------------------------------------------------------------------------------------
class Chirp(_Model):
    wavelength_m: PosFloat = 1.55e-6
    excursion_hz: PosFloat = 8.6e9
    ramp_s: PosFloat = 80e-6
    shape: Literal["triangle"] = "triangle"

    @property
    def rate_hz_per_s(self) -> float:
        return self.excursion_hz / self.ramp_s


class Detector(_Model):
    responsivity_a_per_w: PosFloat = 0.95
    tia_gain_v_per_a: PosFloat = 1.6e4
    temperature_k: PosFloat = 300.0
    balanced: bool = False
    cmrr_db: float = Field(default=-25.0, le=0, allow_inf_nan=False)

    @property
    def effective_cmrr_db(self) -> float:
        """A single photodiode cancels nothing: CMRR = 0 dB (§4.4.2)."""
        return self.cmrr_db if self.balanced else 0.0


#: bits a decimated record keeps beyond the core's effective resolution (config.Adc.record_bits)
RECORD_GUARD_BITS = 4


class Adc(_Model):
    """The digitizer's analogue front end and converter (Table 2-2).

    ``bits`` is the resolution of the converter CORE, which samples at ``max_sample_rate_hz``; a
    record at a lower rate fs is decimated on board, which adds log2(sqrt(max_sample_rate_hz / fs))
    bits (the core's quantization noise spread over a band D times wider than the record's). The host
    asks the digitizer for that record resolution plus ``RECORD_GUARD_BITS`` (:meth:`record_bits`,
    capped at the record format's 16 bits), so the digitizer's rounding of its output words adds
    1/256 of the core's noise power, not as much again (docs/protocols/digitizer.md).
    ``bandwidth_hz`` is the anti-alias low-pass corner the digitizer applies to every record (a corner
    at or above half the record's rate leaves it unfiltered).
    """

    bits: Literal[8, 10, 12, 14, 16] = 8
    input_range_v: PosFloat = 1.0
    bandwidth_hz: PosFloat = 500e6
    max_sample_rate_hz: PosFloat = 1e9
    min_sample_rate_hz: PosFloat = 1e6
    oversample: float = Field(default=2.5, ge=2.0, le=16.0)
    # Real (single-photodiode) beat only: an I/Q receiver is not built yet, so true is refused.
    iq: bool = False

    @field_validator("iq")
    @classmethod
    def _no_iq_yet(cls, v: bool) -> bool:
        if v:
            raise ValueError("an I/Q receiver (adc.iq = true) is not supported yet: the instrument records "
                             "the real beat of one photodiode; set adc.iq = false")
        return v

    def record_bits(self, sample_rate_hz: float, format_bits: int = 16) -> int:
        """Resolution of a record at ``sample_rate_hz``: the core's bits plus the decimation gain
        log2(sqrt(max_sample_rate_hz / fs)) to the nearest bit, plus the guard bits, capped at
        ``format_bits``. At the core's full rate there is nothing to gain or guard: the core's bits."""
        decimation = max(1.0, self.max_sample_rate_hz / float(sample_rate_hz))
        gain = round(0.5 * math.log2(decimation))
        if gain <= 0:
            return int(min(format_bits, self.bits))
        return int(min(format_bits, self.bits + gain + RECORD_GUARD_BITS))


class Link(_Model):
    """Link-budget parameters (Table 2-2) and the reference-path architecture (§4.4.2)."""

    reference: Literal["backreflection", "mzi"] = "backreflection"
    # backreflection (§4.4): light per fibre-array channel, the facet's reflection as LO, power out
    fiber_power_w: PosFloat = 0.1
    backreflection_db: float = Field(default=-34.0, lt=0)
    tx_power_w: PosFloat = 1e-3
    fpsa_losses: Literal["measured", "improved"] = "measured"
    # mzi (Table 2-2)
    laser_power_w: PosFloat = 50e-3
    r_ref: Fraction = 0.1
    eta_tx: Fraction = 0.7
    eta_rx: Fraction = 0.5
    rx_aperture_m: PosFloat | None = None  # None: the lens's entrance pupil (f / N)
    ambient_psd_w_per_hz: NonNegFloat = 1.57e-20
    optical_bandwidth_m: PosFloat = 1e-9
    reflectivity: NonNegFloat = 0.1


class Monitor(_Model):
    """Monitor MZI used for chirp linearization and phase-noise compensation (§2.2, §2.3)."""

    delay_s: PosFloat = 200e-9
    amplitude_v: PosFloat = 0.3
    #: mean optical power on the monitor photodiode, W: sets the channel's shot noise (simulator;
    #: lidard.physics.budget.monitor_noise_asd). 100 uW is an estimate (a 1 % tap of ~10 mW).
    power_w: PosFloat = 100e-6
    # The MZI is also read in quadrature (a 90-degree hybrid or 3x3 coupler and a second digitizer
    # channel, ``mzi_q``): the laser phase is then rebuilt per sample and phase-noise compensation holds
    # at EVERY range (lidard.dsp.pnrecon, issue 15). False is the dissertation's single real MZI: the
    # compensation is exact only where the round trip is a whole multiple of delay_s (docs/benchmarks.md).
    quadrature: bool = False


class ScanDefaults(_Model):
    averages: int = Field(default=1, ge=1, le=100)
    max_range_m: PosFloat = 2.0
    pattern: Literal["raster", "serpentine", "roi", "pixels", "adaptive"] = "raster"
    settle_s: NonNegFloat = 5e-6
    pfa: float = Field(default=1e-6, gt=0, lt=0.1)
    max_returns: int = Field(default=2, ge=1, le=8)
    window: Literal["rectangular", "hann", "blackmanharris"] = "hann"
    # A real (single-photodiode) beat cannot tell a Doppler shift from a range beat when the Doppler
    # allowance exceeds the range beat (§2.1.2): the a-priori speed limit sets what is unambiguous.
    max_speed_mps: float = Field(default=0.4, gt=0, le=100)
    # Laser phase-noise compensation from the monitor MZI recorded with the beat (§2.3,
    # lidard.dsp.pnframe). "auto": on when the round trip of the scan's max_range_m is at least twice the
    # monitor delay (60 m at 200 ns), i.e. where the gate holds bins whose nearest M is >= 2; below
    # that the daemon cannot know the laser's coherence time and the MZI channel doubles the data
    # for little gain. "on"/"off" force it.
    phase_noise_compensation: Literal["auto", "on", "off"] = "auto"
    # A stored chirp linearization is reused only while the laser's TEC temperature stays within this
    # of the temperature it was made at: a DFB's tuning (and so the learned drive) moves with it.
    recalibrate_delta_c: float = Field(default=0.5, gt=0, le=50)


class FpsaDevice(_Model):
    url: str = "bench"          # "bench": the simulated bench's pty; else a pyserial URL or device
    baudrate: int = Field(default=3_000_000, gt=0)
    timeout_s: PosFloat = 0.5


class UsbDevice(_Model):
    usb: str = "bench"          # "bench" or "VID:PID" (hex), e.g. "0x0957:0x2807"
    timeout_s: PosFloat = 2.0


class AwgDevice(UsbDevice):
    # the output stage's limit |offset| + amplitude (docs/protocols/awg.md); no drive beyond it is sent
    max_output_v: float = Field(default=5.0, gt=0, le=50)


class ControllerDevice(_Model):
    host: str = "bench"
    port: int = Field(default=502, ge=0, le=65535)
    device_id: int = Field(default=1, ge=0, le=247)
    timeout_s: PosFloat = 1.0
    max_laser_current_ma: PosFloat = 150.0
    max_hv_v: PosFloat = 60.0
    laser_current_ma: PosFloat = 100.0


class Devices(_Model):
    fpsa: FpsaDevice = FpsaDevice()
    awg: AwgDevice = AwgDevice()
    digitizer: UsbDevice = UsbDevice()
    controller: ControllerDevice = ControllerDevice()


class Effects(_Model):
    """Simulator effects; switching one off skips its cost (and its realism)."""

    phase_noise: bool = True
    mems_dynamics: bool = True
    quantization: bool = True
    noise: bool = True


class Sim(_Model):
    enabled: bool = False
    scene: str = "scenes/cal_letters.toml"
    seed: int = 1
    bench: Literal["child", "embedded"] = "child"
    effects: Effects = Effects()
    # [[sim.faults]] tables, injected by the bench at start. Only their shape is checked here: the
    # catalogue (kinds, parameters) belongs to the simulator, which checks each entry when the bench
    # is built and raises a ConfigError naming it (the daemon side never imports the simulator).
    faults: list[dict] = []

    @field_validator("faults")
    @classmethod
    def _faults_have_a_kind(cls, v: list[dict]) -> list[dict]:
        for i, entry in enumerate(v):
            kind = entry.get("kind")
            if not isinstance(kind, str) or not kind:
                raise ValueError(f"entry {i}: every [[sim.faults]] table needs kind = \"<fault kind>\"")
        return v


class Daemon(_Model):
    host: str = "127.0.0.1"
    port: int = Field(default=8470, ge=0, le=65535)
    data_dir: str = "~/.local/share/lidard"
    # request body limit of the REST API (413 above it); scene uploads are the largest bodies
    max_body_bytes: int = Field(default=1 << 20, ge=1024, le=1 << 30)
    # the control lock's lease lapses this long after the holder's last request (POST /control)
    lease_ttl_s: float = Field(default=300.0, gt=0, le=86_400)
    # wall-clock period of the safety watch thread (interlock/fault flags while laser/HV may be on)
    safety_period_s: float = Field(default=0.02, gt=0, le=1.0)


class Live(_Model):
    """Live publishers besides the REST API (lidard.live): the Foxglove WebSocket server, opt-in."""

    foxglove: bool = False
    # loopback unless the lab says otherwise: the stream has no authentication
    foxglove_host: str = "127.0.0.1"
    foxglove_port: int = Field(default=8765, ge=0, le=65535)  # 0: any free port


class Config(_Model):
    profile: str = "fpsa128"
    lens: str | None = None
    laser: str = "dfb_default"
    chirp: Chirp = Chirp()
    detector: Detector = Detector()
    adc: Adc = Adc()
    link: Link = Link()
    monitor: Monitor = Monitor()
    scan: ScanDefaults = ScanDefaults()
    devices: Devices = Devices()
    sim: Sim = Sim()
    daemon: Daemon = Daemon()
    live: Live = Live()

    # Resolved by load_config (not part of the file format).
    source: str = Field(default="<defaults>", exclude=True)
    # The file read (None: built-in defaults); a simulated bench started as a child process reads it
    # too. Kept by model_dump so a config re-validated with an override still names its file.
    path: str | None = None
    base_dir: str = Field(default=str(CONFIG_DIR), exclude=True)

    @field_validator("profile", "laser")
    @classmethod
    def _name(cls, v: str) -> str:
        if not v or "/" in v or "\\" in v:
            raise ValueError("must be a plain preset name (a file under config/profiles)")
        return v

    # -- resolved views -------------------------------------------------------------------------
    def resolve_path(self, path: str) -> Path:
        p = Path(path).expanduser()
        return p if p.is_absolute() else Path(self.base_dir) / p

    def load_profile(self) -> Profile:
        return load_profile(self.profile, Path(self.base_dir) / "profiles")

    def load_laser(self) -> LaserPreset:
        return load_laser(self.laser, Path(self.base_dir) / "profiles")

    def optics(self) -> FpsaOptics:
        return self.load_profile().optics(self.lens, self.chirp.wavelength_m)

    def link_params(self, profile: Profile | None = None, laser: LaserPreset | None = None) -> LinkParams:
        return link_params(self, profile or self.load_profile(), laser or self.load_laser())


def link_params(cfg: Config, profile: Profile, laser: LaserPreset) -> LinkParams:
    """Turn the configured set-up into the numbers eqs. 2-9..2-21 need."""
    lens = profile.lenses[cfg.lens or profile.default_lens]
    ln = cfg.link
    aperture = ln.rx_aperture_m or lens.aperture_m
    common = dict(
        wavelength_m=cfg.chirp.wavelength_m, ramp_s=cfg.chirp.ramp_s,
        coherence_time_s=laser.coherence_time_s, rin_db_per_hz=laser.rin_db_per_hz,
        responsivity_a_per_w=cfg.detector.responsivity_a_per_w,
        tia_gain_v_per_a=cfg.detector.tia_gain_v_per_a, cmrr_db=cfg.detector.effective_cmrr_db,
        temperature_k=cfg.detector.temperature_k, adc_range_v=cfg.adc.input_range_v,
        adc_bits=cfg.adc.bits, adc_bandwidth_hz=cfg.adc.bandwidth_hz,
        ambient_psd_w_per_hz=ln.ambient_psd_w_per_hz,
        optical_bandwidth_hz=optical_bandwidth_hz(ln.optical_bandwidth_m, cfg.chirp.wavelength_m),
        rx_aperture_m=aperture, reflectivity=ln.reflectivity,
    )
    if ln.reference == "backreflection":
        losses = profile.losses if ln.fpsa_losses == "measured" or profile.losses_improved is None \
            else profile.losses_improved
        return LinkParams(
            source_power_w=ln.fiber_power_w,
            ref_fraction=10 ** (ln.backreflection_db / 10),
            tx_fraction=ln.tx_power_w / ln.fiber_power_w,
            eta_rx=10 ** (-losses.total_db / 10),
            **common,
        )
    return LinkParams(
        source_power_w=ln.laser_power_w, ref_fraction=ln.r_ref,
        tx_fraction=ln.eta_tx * (1 - ln.r_ref), eta_rx=ln.eta_rx, **common,
    )


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------
def _format_validation(source: str, err: ValidationError) -> str:
    parts = []
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key"
        elif e["type"] == "literal_error":
            msg = f"must be {e['ctx']['expected']}"
        got = e.get("input")
        detail = f" (got {got!r})" if got is not None and e["type"] not in ("missing",) and not isinstance(got, dict) else ""
        parts.append(f"{source}: {loc}: {msg}{detail}")
    return "; ".join(parts)


def _read_toml(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read ({exc})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None


def _parse_env_value(raw: str) -> Any:
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw


def apply_env_overrides(data: dict, environ: dict[str, str] | None = None) -> tuple[dict, list[str]]:
    """Return a copy of ``data`` with ``LIDARD__A__B=value`` variables applied, and their names."""
    env = os.environ if environ is None else environ
    out = _deep_copy(data)
    applied = []
    for name, raw in sorted(env.items()):
        if not name.startswith(ENV_PREFIX) or len(name) <= len(ENV_PREFIX):
            continue
        path = [p.lower() for p in name[len(ENV_PREFIX):].split("__")]
        node = out
        for key in path[:-1]:
            nxt = node.setdefault(key, {})
            if not isinstance(nxt, dict):
                raise ConfigError(f"environment {name}: {key} is not a section")
            node = nxt
        node[path[-1]] = _parse_env_value(raw)
        applied.append(name)
    return out, applied


def _deep_copy(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _deep_copy(v) for k, v in d.items()}
    if isinstance(d, list):
        return [_deep_copy(v) for v in d]
    return d


def load_config(path: str | os.PathLike | None = None, *, environ: dict[str, str] | None = None,
                check_presets: bool = True) -> Config:
    """Load and validate a configuration file (default: built-in defaults + env overrides).

    Relative paths inside the file (scenes) resolve against the ``config/`` directory the file lives
    in, or the packaged ``config/`` for the defaults. The named profile and laser preset are loaded too
    (``check_presets``), so a typo there fails here, not in the middle of a scan.
    """
    if path is None:
        data, source, base = {}, "<defaults>", CONFIG_DIR
    else:
        p = Path(path)
        data, source = _read_toml(p), str(p)
        base = p.resolve().parent
        if not (base / "profiles").is_dir():
            base = CONFIG_DIR
    data, applied = apply_env_overrides(data, environ)
    if applied:
        source = f"{source} (+env {', '.join(applied)})"
    try:
        cfg = Config.model_validate({**data, "source": source, "base_dir": str(base),
                                     "path": None if path is None else str(path)})
    except ValidationError as exc:
        raise ConfigError(_format_validation(source, exc)) from None
    if check_presets:
        profile = cfg.load_profile()
        laser = cfg.load_laser()
        if cfg.devices.controller.laser_current_ma > laser.max_current_ma:
            raise ConfigError(f"{source}: devices.controller.laser_current_ma: "
                              f"{cfg.devices.controller.laser_current_ma:g} mA is above the maximum current "
                              f"{laser.max_current_ma:g} mA of laser preset {cfg.laser!r} (max_current_ma)")
        if cfg.lens is not None and cfg.lens not in profile.lenses:
            raise ConfigError(f"{source}: lens: {cfg.lens!r} is not a lens of profile {profile.name}; "
                              f"allowed: {', '.join(sorted(profile.lenses))}")
    return cfg


def available_profiles(profiles_dir: Path = CONFIG_DIR / "profiles") -> list[str]:
    return sorted(p.stem for p in profiles_dir.glob("*.toml") if p.stem != "lasers")


def load_profile(name: str, profiles_dir: Path = CONFIG_DIR / "profiles") -> Profile:
    path = Path(profiles_dir) / f"{name}.toml"
    if name == "lasers" or not path.is_file():
        raise ConfigError(f"profile: {name!r} not found in {profiles_dir}; allowed: "
                          f"{', '.join(available_profiles(Path(profiles_dir)))}")
    data = _read_toml(path)
    try:
        return Profile.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_validation(str(path), exc)) from None


def load_lasers(profiles_dir: Path = CONFIG_DIR / "profiles") -> dict[str, LaserPreset]:
    path = Path(profiles_dir) / "lasers.toml"
    data = _read_toml(path)
    presets = data.get("laser")
    if not isinstance(presets, dict) or not presets:
        raise ConfigError(f"{path}: laser: expected tables [laser.<name>]")
    out = {}
    for name, body in presets.items():
        try:
            out[name] = LaserPreset.model_validate(body)
        except ValidationError as exc:
            raise ConfigError(_format_validation(f"{path}", exc).replace(f"{path}: ", f"{path}: laser.{name}.")) from None
    return out


def load_laser(name: str, profiles_dir: Path = CONFIG_DIR / "profiles") -> LaserPreset:
    presets = load_lasers(profiles_dir)
    if name not in presets:
        raise ConfigError(f"laser: {name!r} is not a preset; allowed: {', '.join(sorted(presets))}")
    return presets[name]
