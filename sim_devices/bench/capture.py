"""The bench as the digitizer's ``SegmentSource``: triggers from the FPGA, beams -> hits -> beat
tones from the world, synthesized at the sample rate the host configured (§2.1 eq. 2-1; §2.4.1;
§4.3.6; §4.4).

:class:`SegmentSynthesizer` is held by :class:`sim_devices.bench.bench.Bench` as ``bench.synthesizer``
and is the digitizer's segment source. It is given what it reads (the configuration, the world, the
laser, the FPGA, AWG and controller, the fault injector, the seed and the hidden truths) and owns
what it keeps (the trajectory cache, the run numbers, the scene clock, the fidelity ledger). Per
batch of triggers it decides which segments see light (laser on, interlock closed, an interlock fault cutting the
batch), which beams emit (the switch dynamics, or the commanded pixel when every switch pulls in),
the hits the world returns, the noise (detector, the converter core's quantization when the record
is decimated on board, Wiener phase noise unless negligible: ``sim_devices.world.fidelity``), and
synthesizes every requested channel: beat (or I/Q through the 90-degree hybrid), the monitor MZI
(its TRUE delay, hidden from the daemon), and the tap photodiode on the emitted light. Segment
noise is seeded from (bench seed, run, first segment index), so a re-read of the same batch gives
the same bytes. The laser's frequency trajectory is computed once per AWG waveform and laser
temperature (1 mK grid) and cached. Tap channel: V = G_tap R eta_tap P_tx sum_beams T_beam plus
white detector noise.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from lidard.config import Config, LaserPreset
from lidard.physics.budget import monitor_noise_asd, quantization_asd
from sim_devices.awg.device import SimAwg
from sim_devices.bench.fault_injector import FaultInjector
from sim_devices.controller.device import ControllerSim
from sim_devices.digitizer.device import (
    CaptureConfig,
    CapturedSegments,
    decimation_filter,
)
from sim_devices.fpsa.device import FpgaSim
from sim_devices.world.fidelity import FidelityLedger, phase_noise_negligible
from sim_devices.world.gauss import NoiseStream, stream_key
from sim_devices.world.laser import DfbLaser
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, MonitorMzi, trajectory
from sim_devices.world.synth_chirp import ChirpTrajectory
from sim_devices.world.synth_parallel import synthesize_read
from sim_devices.world.tec import TecTuning
from sim_devices.world.tolerances import BenchTruth
from sim_devices.world.world import World


@dataclass(frozen=True)
class TapSpec:
    """Monitor photodiode on the FPSA's emission (the digitizer's ``tap`` channel)."""

    fraction: float = 0.01          # 1 % tap coupler on the emitted light
    gain_v_per_a: float = 1.0e4     # monitor TIA
    noise_v_rms: float = 1.0e-3     # white detector + TIA noise per sample


#: a 90-degree hybrid splits the LO and the return four ways: each balanced pair (I or Q) carries
#: R sqrt(P_LO P_rx) of AC current against 2 R sqrt(P_LO P_rx) for the single photodiode of the §4.4
#: circulator set-up, i.e. half the amplitude per channel; each channel keeps the single photodiode's
#: noise (its own TIA and converter) -- docs/physics.md, "The coherent (I/Q) receiver"
HYBRID_CHANNEL_AMPLITUDE = 0.5
# runs whose capture number (:meth:`SegmentSynthesizer._run_index`, the noise seed) is remembered: a capture
# only ever reads the run in progress or the one just before it
RUN_IDS_KEPT = 8
#: pattern pixels the world casts ahead in one call when a read reaches pixels not cast yet: reads
#: hold tens of pixels, and casting ~1000 at once costs a fifth of casting them read by read
#: (World.precast); the cast rays are cached per pixel either way
CAST_AHEAD_PIXELS = 1024


def core_overrange(hits: HitBatch, n_seg: int, input_range_v: float) -> np.ndarray:
    """Segments whose returns, BEFORE the decimation filter, exceed the core's full scale (+-range/2):
    a strong return beyond the gate clips the converter even though the filter hides it from the
    record, and the digitizer flags the segment (what bounds a leak: lidard.physics.decimation)."""
    peak = np.bincount(np.asarray(hits.seg, np.intp), weights=np.abs(hits.amplitude_v), minlength=n_seg)
    return peak > 0.5 * input_range_v


@dataclass(frozen=True)
class LaserParts:
    """The bench's laser: its model, its preset and the TEC tuning of its true temperature (None:
    the temperature effect is off)."""

    model: DfbLaser
    preset: LaserPreset
    tec_tuning: TecTuning | None


@dataclass(frozen=True)
class CaptureDevices:
    """The devices a capture reads: the FPGA (triggers, beams), the AWG (the drive) and the controller
    (laser, interlock, HV; the laser's true temperature)."""

    fpga: FpgaSim
    awg: SimAwg
    controller: ControllerSim


class SegmentSynthesizer:
    """The bench's ``SegmentSource``: the segments the digitizer streams, synthesized from the world."""

    def __init__(self, cfg: Config, world: World, laser: LaserParts, devices: CaptureDevices,
                 faults: FaultInjector, *, seed: int, truth: BenchTruth) -> None:
        self.cfg = cfg
        self.world = world
        self.laser = laser.model
        self.laser_preset = laser.preset
        self.tec_tuning = laser.tec_tuning
        self.fpga, self.awg, self.controller = devices.fpga, devices.awg, devices.controller
        self.faults = faults
        self.seed = seed
        self._truth = truth
        #: guards the world and the synthesis state: a capture against a scene change
        self.lock = threading.RLock()
        self._traj_key: tuple | None = None
        self._traj_codes: np.ndarray | None = None
        self._traj: ChirpTrajectory | None = None
        self._scene_hold = False                 # hold_scene_clock
        self._scene_epoch_s: float | None = None
        self.segments_synthesized = 0
        # FPGA run start (virtual s) -> 1, 2, ... in the order runs are first captured: the noise seed
        # (see _run_index)
        self._run_ids: dict[float, int] = {}
        self._runs_captured = 0
        self.fidelity = FidelityLedger()  # which effects each captured batch modelled or skipped
        self.tap = TapSpec()
        self._cast_to: tuple[float | None, int, int] | None = None   # (run start, first, end) cast ahead

    def hold_scene_clock(self, hold: bool) -> None:
        """Scene time counts from the first trigger of the next run and runs on across the following
        runs while held (the frames of a stream are one run each; a point's ``t`` counts from the
        stream's first trigger); released, each run starts its scene at t = 0 again."""
        with self.lock:
            self._scene_hold = bool(hold)
            self._scene_epoch_s = None

    def _run_first_trigger_s(self) -> float:
        sched = self.fpga.schedule
        first = 0.0 if sched is None else float(sched.trigger_s(np.array([0]))[0])
        if self._scene_hold:
            if self._scene_epoch_s is None:
                self._scene_epoch_s = first
            return self._scene_epoch_s
        return first

    def trajectory(self) -> ChirpTrajectory:
        """The laser's frequency trajectory for the AWG's waveform at the laser's true temperature
        (cached per waveform and 1 mK of temperature)."""
        awg, temp_c = self.awg, None
        if self.tec_tuning is not None:   # keyed on the 1 mK grid: not recomputed every batch
            temp_c = self.tec_tuning.quantise(self.controller.model.laser_temperature_c())
        # what the drive in volts is made of, compared by value (a read costs a compare of the AWG's
        # int16 codes against a kept copy, not a hash of the float64 drive)
        key = (float(awg.amplitude_v), float(awg.offset_v), float(awg.sample_rate_hz), bool(awg.output_on), temp_c)
        if self._traj is None or self._traj_codes is None or key != self._traj_key \
                or not np.array_equal(awg.codes, self._traj_codes):
            drive, fs = awg.drive_volts()
            if not awg.output_on:
                drive = np.zeros_like(drive)
            laser = self.laser
            if self.tec_tuning is not None and temp_c is not None:
                laser = self.tec_tuning.laser_at(self.laser, temp_c)
            self._traj = trajectory(laser, drive, fs)
            self._traj_key, self._traj_codes = key, np.array(awg.codes, copy=True)
        return self._traj

    def _tap_codes(self, path_sum: np.ndarray, adc: AdcSpec, first: int):
        """Monitor photodiode codes: a DC level per segment (sum of emitting path transmissions)
        plus white noise, quantized like every channel; clipped segments are flagged."""
        volts_per_path = self.tap_volts_per_beam()
        rng = np.random.default_rng([self.seed, 0x7A9, int(first)])
        v = (volts_per_path * path_sum)[:, None] + self.tap.noise_v_rms * rng.standard_normal(
            (path_sum.size, adc.n_samples))
        lo_code, hi_code = -(2 ** (adc.bits - 1)), 2 ** (adc.bits - 1) - 1
        raw = np.rint(v / adc.lsb_v)
        over = (raw < lo_code).any(axis=1) | (raw > hi_code).any(axis=1)
        return np.clip(raw, lo_code, hi_code).astype(np.int16), over

    def _core_asd(self, capture: CaptureConfig) -> float:
        """White-noise ASD of the converter core's quantization in a decimated record.

        The simulated converter is the one the configuration describes (``adc.bits`` at
        ``adc.max_sample_rate_hz``). A record the host configured wider than the core
        (``CaptureConfig.resolution_bits`` > core bits: config.Adc.record_bits, core bits + the
        decimation gain + guard bits) was decimated on board, so the core's quantization noise,
        LSB^2/12 over its full Nyquist band, is in it as white noise; the digitizer then rounds the
        record to the configured resolution. A record at the core's own resolution gets only that
        rounding."""
        a = self.cfg.adc
        if int(capture.resolution_bits) <= a.bits:
            return 0.0
        return quantization_asd(a.input_range_v, a.bits, a.max_sample_rate_hz)

    def monitor_asd(self, capture: CaptureConfig) -> float:
        """White-noise ASD of the monitor-MZI channel: its photodiode's shot noise and the laser's
        RIN (``sim.effects.noise``), plus the decimated core's quantization noise (:meth:`_core_asd`,
        ``sim.effects.quantization``)."""
        eff, mon = self.cfg.sim.effects, self.cfg.monitor
        asd = 0.0
        if eff.noise:
            asd = monitor_noise_asd(mon.amplitude_v, mon.power_w, self.cfg.detector.responsivity_a_per_w,
                                    self.laser_preset.rin_db_per_hz)["total"]
        if eff.quantization:
            asd = float(np.hypot(asd, self._core_asd(capture)))
        return asd

    def tap_volts_per_beam(self) -> float:
        """Tap level of one fully open beam (what a healthy pixel reads), V."""
        link = self.world.link
        return (self.tap.gain_v_per_a * self.cfg.detector.responsivity_a_per_w * self.tap.fraction
                * link.source_power_w * link.tx_fraction)

    def _run_index(self) -> int:
        """Which captured run this is (0 before any run), for the noise seed.

        Not the run's virtual start time: the host's retry backoffs advance the virtual clock, and
        those depend on wall-clock timeouts (a loaded machine), so a seed from the start time gave
        different noise, a different ILC drive and different ranges from one run of the same
        programme to the next. The count of runs captured is the same however long they waited.
        Only the newest runs' numbers are kept (captures read the run in progress, or one just cut
        short): a bench that runs for weeks does not keep one entry per run it ever captured.
        """
        start = self.fpga.run_start_s
        if start is None:
            return 0
        idx = self._run_ids.get(float(start))
        if idx is None:
            self._runs_captured += 1
            idx = self._run_ids[float(start)] = self._runs_captured
            while len(self._run_ids) > RUN_IDS_KEPT:
                del self._run_ids[next(iter(self._run_ids))]      # the oldest (insertion order)
        return idx

    def _phase_noise_linewidth(self, linewidth_hz: float, hits, want_mzi: bool, noise_asd: float) -> float:
        """The linewidth this batch is synthesized with: 0 when, for every hit, the beat's phase noise
        is below the bounds of :mod:`sim_devices.world.fidelity` and no monitor channel needs it."""
        if linewidth_hz <= 0:
            return 0.0
        c = self.cfg.chirp
        skip = not want_mzi and (hits is None or phase_noise_negligible(
            hits.tau_s, hits.amplitude_v, linewidth_hz, noise_asd, c.ramp_s, c.rate_hz_per_s))
        self.fidelity.note("phase_noise", not skip)
        return 0.0 if skip else linewidth_hz

    def capture(self, first: int, count: int, cfg: CaptureConfig) -> CapturedSegments:
        with self.lock:
            return self._capture(first, count, cfg)

    def _capture(self, first: int, count: int, cfg: CaptureConfig) -> CapturedSegments:
        eff = self.cfg.sim.effects
        capture_s = cfg.record_length / cfg.sample_rate_hz
        trig = (self.fpga.triggers(first, count, capture_s) if cfg.armed_at_s is None
                else self.fpga.triggers_since(cfg.armed_at_s, first, count, capture_s))
        n = len(trig)
        st = self.controller.state
        light = bool(st.laser_on and st.interlock_closed)
        # the HV583 outputs carry the controller's HV: which switches pull in is the FPGA's
        # (per-switch hysteresis); an HV output switched off during a run still darkens it
        switches = bool(st.hv_on)
        # Light per segment: an interlock that opens inside this batch (at a virtual time or after
        # a number of segments) darkens the segments from that trigger on.
        lit = np.full(n, light)
        cut_s = self.faults.interlock_cut_s(trig.t_s, self.segments_synthesized)
        if cut_s is not None:
            lit &= np.asarray(trig.t_s) < cut_s
        gain = self.faults.overrange_gain
        iq = "beat_i" in cfg.channels
        adc = AdcSpec(sample_rate_hz=cfg.sample_rate_hz, n_samples=cfg.record_length, bits=cfg.bits,
                      input_range_v=cfg.input_range_v, iq=iq, quantize=True)
        rows, cols, trans, beam_seg = self._emitted_beams(trig, n, eff.mems_dynamics)
        emitting = lit[beam_seg] & switches
        hits = bh = None
        if light and switches and n and emitting.any():
            hits, bh = self._beat_hits(trig, (rows, cols, trans, beam_seg), emitting, gain, iq)
        syn = self._synthesize(cfg, adc, n, hits, bh, light, gain, first)
        codes, over = self._records(syn, cfg, n, hits, lit)
        if "tap" in cfg.channels and n:
            j = cfg.channels.index("tap")
            power = np.zeros(n)
            if switches:
                np.add.at(power, beam_seg, np.where(lit[beam_seg], trans, 0.0))
            codes[:, j], over[:, j] = self._tap_codes(power, adc, first)
        self.segments_synthesized += n
        return CapturedSegments(trigger_time_s=np.asarray(trig.t_s, dtype=np.float64), codes=codes,
                                overrange=over)

    def _emitted_beams(self, trig, n: int, mems_dynamics: bool):
        """(rows, cols, path transmission, segment) of the beams of a batch: from the switch dynamics
        (ghost beams, stuck switches, switches the HV does not pull in), or the commanded pixel at
        full transmission when none of that can change the answer."""
        # a stuck switch only shows through the switch dynamics (which beams actually emit)
        beams_from_dynamics = (mems_dynamics or bool(self.fpga.stuck_switches)
                               or not self.fpga.pulls_in_every_switch())
        if beams_from_dynamics:
            return (trig.beam_row, trig.beam_col, trig.beam_transmission,
                    np.asarray(trig.beam_trigger, np.intp))
        return trig.row, trig.col, np.ones(n), np.arange(n)

    def _beat_hits(self, trig, beams, emitting: np.ndarray, gain: float, iq: bool):
        """The world's returns of the emitting beams as a HitBatch (None when nothing returns), and
        the world's answer (for the fidelity ledger)."""
        rows, cols, trans, beam_seg = beams
        self._cast_ahead(trig)
        chirp = np.asarray(trig.index)[np.asarray(beam_seg)[emitting]]
        # scene time: since the run's first trigger (a point's t counts from the same trigger)
        t_scene = np.asarray(trig.t_s)[np.asarray(beam_seg)[emitting]] - self._run_first_trigger_s()
        bh = self.world.beam_hits(rows[emitting], cols[emitting], trans[emitting], chirp=chirp, t_s=t_scene)
        if not bh.beam.size:
            return None, bh
        phase = None
        if bh.speckle_phase_rad is not None:  # others keep the synthesis' 2 pi nu0 tau
            plain = 2.0 * np.pi * np.mod(self.trajectory().nu0_hz * bh.tau_s, 1.0)
            phase = np.where(np.isnan(bh.speckle_phase_rad), plain, bh.speckle_phase_rad)
        hits = HitBatch(seg=np.asarray(beam_seg[emitting])[bh.beam].astype(np.intp),
                        tau_s=bh.tau_s, amplitude_v=bh.amplitude_v * gain * (HYBRID_CHANNEL_AMPLITUDE if iq else 1.0),
                        doppler_hz=-2.0 * bh.velocity_mps / self.cfg.chirp.wavelength_m,
                        phase_rad=phase)
        return hits, bh

    def _cast_ahead(self, trig) -> None:
        """The run's next CAST_AHEAD_PIXELS pattern pixels cast in one call (World.precast) when this
        read reaches a pixel past the last look-ahead."""
        if not len(trig.pixel_index):
            return
        run, first, last = self.fpga.run_start_s, int(trig.pixel_index[0]), int(trig.pixel_index[-1])
        if self._cast_to is not None and self._cast_to[0] == run and self._cast_to[1] <= first and last < self._cast_to[2]:
            return
        rows, cols = self.fpga.pattern_pixels(first, CAST_AHEAD_PIXELS)
        self.world.precast(rows, cols)
        self._cast_to = (run, first, first + CAST_AHEAD_PIXELS)

    def _synthesize(self, cfg: CaptureConfig, adc: AdcSpec, n: int, hits, bh, light: bool, gain: float,
                    first: int):
        """The batch's records from the synthesis: noise levels, phase noise and the monitor MZI
        (its TRUE delay) as the effects and the light allow; notes the effects in the ledger."""
        eff = self.cfg.sim.effects
        noise_asd = gain * self.world.white_noise_asd_v() if (eff.noise and light) else 0.0
        if eff.quantization:
            noise_asd = float(np.hypot(noise_asd, self._core_asd(cfg)))
        mzi_asd = self.monitor_asd(cfg) if light else 0.0
        linewidth = self.laser.linewidth_hz if (eff.phase_noise and light) else 0.0
        want_mzi = "mzi" in cfg.channels and light
        # the quadrature output exists only with the hybrid fitted ([monitor] quadrature); without
        # it the mzi_q input is unconnected and reads 0
        want_q = want_mzi and "mzi_q" in cfg.channels and self.cfg.monitor.quadrature
        linewidth = self._phase_noise_linewidth(linewidth, hits, want_mzi, noise_asd)
        if hits is not None:
            self.fidelity.note("doppler", bool(np.any(hits.doppler_hz != 0)))
            self.fidelity.note("speckle", hits.phase_rad is not None)
            self.fidelity.note("mixed_pixels", bh.mixed_beams > 0)   # hits come from bh
        run = self._run_index()
        a = self.cfg.adc
        aa = decimation_filter(cfg.sample_rate_hz, a.max_sample_rate_hz, a.stopband_db)
        # a large read in parts on the bench's threads: the white noise of a record is a function of
        # (seed, run, trigger index), the phase noise seeded as a read from each part's first segment
        return synthesize_read(self.trajectory(), adc, np.zeros(n), hits,
                               lambda s: np.random.default_rng([self.seed, run, int(first) + s]),
                               noise=NoiseStream(stream_key(self.seed, run), int(first)),
                               effects=Effects(noise_asd_v_per_rthz=noise_asd, beat_filter=aa, linewidth_hz=linewidth,
                                               iq_imbalance=(self._truth.iq_gain, self._truth.iq_phase_rad)),
                               mzi=MonitorMzi(self._truth.mzi_delay_s, self.cfg.monitor.amplitude_v, mzi_asd,
                                              quadrature=want_q) if want_mzi else None)

    @staticmethod
    def _records(syn, cfg: CaptureConfig, n: int, hits, lit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(codes (n, channels, samples) int16, overrange (n, channels)) in the host's channel order."""
        by_name = {"beat": syn.beat, "beat_i": syn.beat, "beat_q": syn.beat_q, "mzi": syn.mzi, "mzi_q": syn.mzi_q}
        # a scan's one beat channel: the synthesized records are the batch's codes, no copy
        single = tuple(cfg.channels) in (("beat",), ("beat_i",))
        codes = syn.beat[:, None, :] if single else np.zeros((n, len(cfg.channels), cfg.record_length), np.int16)
        over = np.zeros((n, len(cfg.channels)), dtype=bool)
        for j, name in enumerate(cfg.channels):
            data = by_name.get(name)
            if data is not None:
                if not single:
                    codes[:, j] = data
                if name in syn.channels:
                    over[:, j] = syn.overrange[:, syn.channels.index(name)]
                if name in ("beat", "beat_i", "beat_q") and hits is not None:
                    over[:, j] |= core_overrange(hits, n, cfg.input_range_v)
                if name in ("mzi", "mzi_q") and not lit.all():
                    codes[~lit, j] = 0  # no light, no MZI fringes
        return codes, over
