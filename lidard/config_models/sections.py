"""The sections of a configuration file (``[chirp]``, ``[detector]``, ``[adc]``, ``[link]``, ``[monitor]``,
``[scan]``, ``[devices.*]``, ``[sim]``, ``[daemon]``, ``[live]``).

The chirp follows dissertation §4.4.1, the detector/TIA/ADC and link budget Table 2-2 and §4.4.2.
:class:`lidard.config.Config` composes them; every model here is re-exported by :mod:`lidard.config`.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, field_validator, model_serializer, model_validator

from .base import Fraction, NonNegFloat, PosFloat, _Model


class Chirp(_Model):
    wavelength_m: PosFloat = 1.55e-6
    excursion_hz: PosFloat = 8.6e9
    ramp_s: PosFloat = 80e-6
    # "three_segment" (default): up ramp, down ramp, then a constant-frequency segment whose beat is the
    # Doppler shift alone: signed velocity with one photodiode and no speed prior (lidard.dsp.ranging.threeseg).
    # "triangle": up + down only; a real beat then needs scan.max_speed_mps as a prior (static scenes).
    shape: Literal["triangle", "three_segment"] = "three_segment"
    # three_segment: the constant segment lasts lambda / (2 velocity_resolution_mps) (its Doppler bin)
    velocity_resolution_mps: float = Field(default=0.01, gt=0, le=10)
    # Where the linearization makes the chirp linear (lidard.instrument.calibration.linearization):
    # "core" (default) the centre of each ramp (80 %, learning 92 %); "range" the whole range window the
    # range FFT uses (90 %, learning 95 %). Far-range work needs "range": "core" leaves a range error of
    # up to 0.6 mm over 0.8-45 m that no scale and offset absorb (0.03 mm with "range"); a bench ranging
    # within a few metres does not, and "range" costs it 3-4x the linearization's CPU
    # (docs/measured/26_range_linearity.md). In the linearization's key only when not the default.
    linear_window: Literal["core", "range"] = "core"

    @model_serializer(mode="wrap")
    def _dump(self, handler):
        # the default stays out of every dump, so the calibration caches and set-up hashes of a
        # configuration that does not set it are those it had before the key existed
        data = handler(self)
        if self.linear_window == "core" and isinstance(data, dict):
            data.pop("linear_window", None)
        return data

    @model_validator(mode="before")
    @classmethod
    def _band_moved(cls, data):
        # The Doppler band sizes the digitizer for one scan, not the drive waveform: it is a scan
        # request (scan.max_speed_mps, like scan.max_range_m) and stays out of the linearization's key.
        if isinstance(data, dict) and "doppler_band_mps" in data:
            raise ValueError("chirp.doppler_band_mps is now scan.max_speed_mps (a scan request: "
                             "`lidarctl scan --max-speed`, max_speed_mps in POST /scans)")
        return data

    @property
    def rate_hz_per_s(self) -> float:
        return self.excursion_hz / self.ramp_s

    @property
    def cw_s(self) -> float:
        """Length of the constant-frequency segment (0 for a triangle), rounded up to a whole us."""
        if self.shape != "three_segment":
            return 0.0
        return math.ceil(self.wavelength_m / (2 * self.velocity_resolution_mps) * 1e6 - 1e-6) * 1e-6

    @property
    def period_s(self) -> float:
        """One trigger period: up + down ramp (+ the constant segment)."""
        return 2 * self.ramp_s + self.cw_s


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
    at or above half the record's rate leaves it unfiltered). ``stopband_db``: the stop-band rejection
    of the on-board decimation filter (data sheet; lidard.physics.decimation): it sets the range gate's
    alias ceiling, and the simulated digitizer's filter.
    """

    bits: Literal[8, 10, 12, 14, 16] = 8
    input_range_v: PosFloat = 1.0
    bandwidth_hz: PosFloat = 500e6
    max_sample_rate_hz: PosFloat = 1e9
    min_sample_rate_hz: PosFloat = 1e6
    oversample: float = Field(default=2.5, ge=2.0, le=16.0)
    stopband_db: float = Field(default=100.0, gt=0, le=200)
    # Spurious-free dynamic range of the receiver chain (TIA and digitizer together, data sheet): how far
    # below a full-scale tone its strongest harmonic stays while nothing clips. It bounds the harmonic
    # a return can make at any smaller amplitude (a smooth nonlinearity's h-th harmonic falls by h - 1 dB
    # per dB of back-off), so a peak at 2x / 3x a stronger one's beat is a real surface when it stands
    # above that bound (lidard.dsp.detect.cfar); a clipped record's points are never valid. 40 dBc: an
    # 8-bit digitizer's ~45-50 dBc less the TIA's share.
    sfdr_dbc: float = Field(default=40.0, gt=0, le=150)
    # false: one photodiode, the real beat (channel "beat"); true: a coherent receiver (90-degree hybrid,
    # two photodiodes, channels "beat_i" and "beat_q"; the monitor MZI stays on its own channel), whose
    # two-sided spectrum gives the beat's sign on the triangle alone (lidard.dsp.ranging.iqbalance)
    iq: bool = False

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
    # at EVERY range (lidard.dsp.phasenoise.reconstruct). False is the dissertation's single real MZI: the
    # compensation is exact only where the round trip is a whole multiple of delay_s (docs/benchmarks.md).
    quadrature: bool = False


class ScanDefaults(_Model):
    averages: int = Field(default=1, ge=1, le=100)
    max_range_m: PosFloat = 2.0
    pattern: Literal["raster", "serpentine", "roi", "pixels", "adaptive"] = "raster"
    settle_s: NonNegFloat = 5e-6
    # the rate of valid false points per range cell (c / 2B of the searched band) in noise alone; the
    # per-ramp detector runs at the looser level this implies (lidard.dsp.ranging.points)
    pfa: float = Field(default=1e-11, gt=0, lt=0.1)
    # returns a pixel may give (the model order's ceiling, lidard.dsp.ranging.order). 3: double glazing in
    # front of a wall is three surfaces in one beam, and with 2 the order test refused the pixel whole
    # (903 of 903 such pixels of a hold-out scene gave no valid point; 880 give all three now). The DSP
    # costs ~8 % more CPU (a CAL frame: 2.89-3.03 s against 3.16-3.25 s; benchmarks/frame.py, 27 Nov).
    max_returns: int = Field(default=3, ge=1, le=8)
    window: Literal["rectangular", "hann", "blackmanharris"] = "hann"
    # The fastest radial speed a scan is asked to measure (a request, like max_range_m; per scan:
    # `lidarctl scan --max-speed`, max_speed_mps in POST /scans). It sizes the digitizer: the ADC band
    # must hold the range beat plus this Doppler shift (§2.1.2), so a static scene pays for no Doppler
    # allowance (0.4 m/s: 5 MHz x 1,190 samples a three-segment record at 2 m; 10 m/s: 40 MHz x 9,520).
    # Three-segment chirp and I/Q receiver: a band, not a prior (a target beyond it is flagged, never
    # ranged). Triangle on a real receiver: also the a-priori limit that makes a pair unambiguous.
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
    # Linearization health (lidard.instrument.calibration.health): before each scan the
    # monitor MZI records ``linearity_check_records`` periods of the drive in use; when their RMS error
    # against the ideal chirp exceeds ``linearity_threshold_hz`` the chirp is re-linearized first (the
    # temperature rule above stays as a second trigger). The default sits between the error of a fresh
    # linearization and that of a 0.2 C TEC step (benchmarks/linearity_health.py, docs/benchmarks.md).
    linearity_check: bool = True
    linearity_threshold_hz: float = Field(default=200e3, gt=0, le=1e9)
    linearity_check_records: int = Field(default=16, ge=2, le=512)


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


class Tolerances(_Model):
    """What a real bench has and the daemon does not know: the simulated bench draws each
    true value once (seeded by ``seed``, or ``sim.seed`` when None) uniformly within +- its bound, or
    takes the bound itself with ``draw = false`` (sensitivity studies). A bound of 0 switches that
    tolerance off; ``enabled = false`` switches them all off (the bench then matches the nominal
    configuration exactly: every instrument identical to its data sheet). The daemon never reads this section: it learns the
    truth only through its calibrations."""

    enabled: bool = True
    draw: bool = True
    seed: int | None = None
    mzi_delay_rel: float = Field(default=0.01, ge=0, le=0.05)      # true delay = nominal x (1 + eps)
    zero_offset_m: float = Field(default=0.05, ge=0, le=1.0)        # reference reflection -> lens path
    focal_rel: float = Field(default=0.01, ge=0, le=0.05)           # true f = nominal x (1 + eps)
    decentre_px: float = Field(default=1.0, ge=0, le=10.0)          # per axis, in pixel pitches
    rotation_deg: float = Field(default=0.5, ge=0, le=5.0)          # array about the optical axis
    k1: float = Field(default=0.1, ge=0, le=1.0)                    # radial distortion (see Pointing)
    # the coherent receiver's 90-degree hybrid and photodiode pair (adc.iq; lidard.dsp.ranging.iqbalance)
    hybrid_gain_db: float = Field(default=0.5, ge=0, le=3.0)        # Q / I gain ratio, dB
    hybrid_phase_deg: float = Field(default=5.0, ge=0, le=20.0)     # quadrature phase error
    # the TEC coefficients are the laser's physics, taken as given (not drawn); the drift of the chip's
    # true temperature is the random part (sim_devices.world.tec)
    tec_tuning_hz_per_c: float = Field(default=-12e9, le=0)         # DFB carrier shift per degree C
    tec_response_per_c: float = Field(default=0.002, ge=0, le=0.05)  # relative FM-response change per C
    tec_drift_c: float = Field(default=0.05, ge=0, le=5.0)          # slow drift of the TEC's true temperature (rms)
    tec_drift_period_s: float = Field(default=600.0, gt=0)          # its correlation time


class Sim(_Model):
    enabled: bool = False
    scene: str = "scenes/cal_letters.toml"
    seed: int = 1
    bench: Literal["child", "embedded"] = "child"
    effects: Effects = Effects()
    tolerances: Tolerances = Tolerances()
    # a scan on this bench with no range/pointing calibration of its set-up first runs the bench's factory
    # calibration (plates, then spheres, placed through the bench and measured through the instruments;
    # lidard.jobs.guided): the one-shot `lidarctl scan --sim` (kept in the user's cache) and the daemon's
    # first scan. `lidarctl scan --sim --uncalibrated` skips it for one run.
    factory_calibration: bool = True
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
