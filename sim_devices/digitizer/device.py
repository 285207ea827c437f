"""Simulated digitizer (ADC): the vendor-protocol peer on the simulated USB bus.

§4.4.1: the beat signal from the photodetector is sampled by the ADC, one segment per external
trigger (one chirp at one FPSA pixel), and sent to the PC. The bench injects a ``SegmentSource``
that synthesizes the codes of requested segments (beat, MZI, I/Q channels) from the world model.

Memory stays bounded: segments are pulled from the source lazily, in batches of about
``batch_bytes``, as the host drains bulk-IN; never a whole frame at once. Time is modelled on the
shared ``VirtualClock``: before a segment is served the clock moves to its trigger time plus the
record duration (the capture must have happened), and every bulk-IN transfer advances it by
bytes / ``usb_rate_bytes_s`` (the modelled bus throughput, 40 MB/s by default).

Front end (SET_RESOLUTION, SET_BANDWIDTH): the source's codes stand for the analog input (16-bit
codes are 15 uV steps on a 1 V range). The digitizer band-limits every channel with its anti-alias
filter (signal and noise alike, since both are in the codes) and then quantizes to the requested
resolution, as the converter does: filter first, quantizer last. The filter stands in for a
digitizer's decimation filter: zero phase (linear-phase like an FIR decimator, so a trigger-aligned
record keeps its timing and the range does not shift), steep (a 4th-order Butterworth run forward
and backward, effective order 8). Its amplitude response, the formula docs/protocols/digitizer.md
gives, is

    |G(f)| = 1 / (1 + (sqrt(2) - 1) * (tan(pi f / fs) / tan(pi f_c / fs)) ** (2 * ANTI_ALIAS_ORDER))

i.e. -3.01 dB at the corner f_c and about -42 dB at 2 f_c (fs = 20 f_c). Running a Butterworth of
corner f_d forward and backward squares its magnitude, 1 / (1 + (t / t_d)**(2N)) with
t = tan(pi f / fs); the design corner t_d = t_c * (sqrt(2) - 1) ** (-1 / (2N)) puts the -3 dB point
of the pair at f_c. A corner at or above fs / 2 leaves the record as it is.

Decimation filter: a record below the core's rate is decimated on board, behind a
digital filter that tracks the record rate (pass band to 0.4 fs, stop band from 0.6 fs,
``stopband_db`` down; lidard.physics.decimation). It must act before the rate reduction, so it is
applied by the synthesis to every return at its true beat frequency (:func:`decimation_filter`,
sim_devices.world.antialias); the corner filter above then acts on the record as before.

Wire format: drivers/digitizer/protocol.py and docs/protocols/digitizer.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from drivers.digitizer import protocol as p
from lidard.physics.decimation import PASSBAND_FRACTION, DecimationFilter
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.front_end import (  # noqa: F401  (re-exported: tests, benchmarks, the bench)
    ANTI_ALIAS_ORDER,
    band_limit,
    butter,
    front_end,
    quantize_codes,
    quantize_int16_into,
    quantize_int_codes,
    sosfiltfilt,
    write_samples,
)
from sim_devices.usb.backend import (
    DeviceSpec,
    EndpointSpec,
    SimUsbDevice,
    usb_stall,
    usb_timeout,
)
from sim_devices.world import synth_jit
from sim_devices.world.antialias import BeatFilter

SAMPLE_RATE_MIN_HZ = 1_000
SAMPLE_RATE_MAX_HZ = 5_000_000_000
RECORD_LENGTH_MAX = 16 * 1024 * 1024
SEGMENTS_MAX = 1 << 24
RANGE_MV_MIN = 10
RANGE_MV_MAX = 10_000


@dataclass(frozen=True)
class CaptureConfig:
    sample_rate_hz: float
    record_length: int
    channels: tuple[str, ...]
    bits: int
    input_range_v: float
    #: ADC resolution and anti-alias corner the digitizer applies after the source (information)
    resolution_bits: int = 16
    bandwidth_hz: float = 0.0
    #: virtual time of the ARM: segment k is the k-th trigger after it, whichever FPGA run fired it
    #: (None: the k-th trigger of the FPGA's current run, for sources driven without a digitizer)
    armed_at_s: float | None = None


@dataclass
class CapturedSegments:
    """What the source returns: trigger times (float64 s, (count,)), int16 codes
    (count, n_channels, record_length) already quantized to ``bits``, overrange (count, n_channels)."""

    trigger_time_s: np.ndarray
    codes: np.ndarray
    overrange: np.ndarray


class SegmentSource(Protocol):
    def capture(self, first: int, count: int, cfg: CaptureConfig) -> CapturedSegments:
        """Segments ``first..first+count-1``. Must be a function of the indices: the digitizer
        may ask again for segments the host re-reads."""
        ...


class SimDigitizer(SimUsbDevice):
    """Simulated digitizer: configuration, arm/abort/status, lazy segment stream on EP 0x81."""

    def __init__(self, clock: VirtualClock, source: SegmentSource, *, serial: str = "SIM0002",
                 usb_rate_bytes_s: float = 40e6, batch_bytes: int = 4 << 20) -> None:
        super().__init__()
        self.spec = DeviceSpec(
            vid=p.DIGITIZER_VID, pid=p.DIGITIZER_PID, manufacturer="lidard-sim", product="ADC-2CH",
            serial=serial, interface_class=0xFF, interface_subclass=0x00, interface_protocol=0x00,
            endpoints=(EndpointSpec(p.EP_DATA_IN),),
        )
        self.clock = clock
        self.source = source
        self.usb_rate_bytes_s = float(usb_rate_bytes_s)
        self.batch_bytes = int(batch_bytes)
        self.config = p.Config(sample_rate_hz=250_000_000, record_length=20_000, segments=1,
                               input_range_mv=1000, channel_mask=p.CHANNEL_BITS["beat"], bits=16)
        self._reset_acquisition()
        self.last_refused_request = 0
        #: largest batch actually pulled from the source (tests check memory stays bounded)
        self.max_batch_segments = 0

    def _reset_acquisition(self) -> None:
        self.state = p.State.IDLE
        self.segments_captured = 0
        self.overrange_count = 0
        self._armed_cfg: p.Config | None = None
        self._armed_at_s: float | None = None
        self._next = 0          # next segment index to stream
        self._end = 0           # one past the last segment requested by READ_SEGMENTS
        self._batch: memoryview | None = None
        self._batch_pos = 0
        self.segments_sent = 0

    def capture_config(self, c: p.Config | None = None) -> CaptureConfig:
        c = c or self.config
        return CaptureConfig(float(c.sample_rate_hz), c.record_length, c.channels, c.bits,
                             c.input_range_mv / 1000.0, c.resolution_bits, float(c.bandwidth_hz),
                             self._armed_at_s if c is self._armed_cfg else None)

    # ------------------------------------------------------------------------ control

    def _refuse(self, req: int, why: str):
        self.last_refused_request = req
        return usb_stall(f"digitizer request 0x{req:02x}: {why}")

    def handle_ctrl(self, bm, req, w_value, w_index, data, w_length):
        try:
            r = p.Req(req)
        except ValueError:
            raise self._refuse(req, "unknown request") from None
        if bm & 0x80:
            return self._answer_in(r, req, w_length)
        if self.state in (p.State.ARMED, p.State.CAPTURING) and r in _SETTINGS:
            raise self._refuse(req, "configuration locked while armed")
        try:
            if r in _SETTINGS:
                self.config = self._setting(r, req, w_value, data or b"")
            elif r is p.Req.ARM:
                self._reset_acquisition()
                self.state = p.State.ARMED
                self._armed_cfg = self.config
                self._armed_at_s = self.clock.now()
                # the acquisition's size is known from here: the synthesis decides its compiled
                # kernels' load on it (its records carry the bench's white noise)
                c = self.config
                synth_jit.expect(c.segments * c.record_length * len(c.channels))
            elif r is p.Req.ABORT:
                self._reset_acquisition()
            elif r is p.Req.READ_SEGMENTS:
                first, count = p.dec_read_segments(data or b"")
                cfg = self._armed_cfg
                if cfg is None or count < 1 or first + count > cfg.segments:
                    raise self._refuse(req, f"READ_SEGMENTS({first},{count}) outside acquisition")
                self._next, self._end = first, first + count
                self._batch, self._batch_pos = None, 0
            else:
                raise self._refuse(req, "not an OUT request")
        except p.DigitizerProtocolError as exc:
            raise self._refuse(req, str(exc)) from None
        return len(data or b"")

    def _answer_in(self, r: p.Req, req: int, w_length: int) -> bytes:
        if r is p.Req.IDENTIFY:
            s = self.spec
            return f"{s.manufacturer},{s.product},{s.serial},1.0".encode()[:w_length]
        if r is p.Req.GET_STATUS:
            return p.encode_status(p.Status(self.state, self.segments_captured, self.overrange_count,
                                            self.last_refused_request, self.segments_sent))
        if r is p.Req.GET_CONFIG:
            return p.encode_config(self.config)
        raise self._refuse(req, "not an IN request")

    def _setting(self, r: p.Req, req: int, w_value: int, data: bytes) -> p.Config:
        """The configuration after setting request ``r`` (refused: a STALL naming the value)."""
        c = self.config
        if r is p.Req.SET_CHANNELS:
            p.validate_mask(w_value)
            return _replace(c, channel_mask=w_value)
        if r is p.Req.SET_FORMAT:
            p.bytes_per_sample(w_value)
            # a new format starts at its full resolution (SET_RESOLUTION may lower it)
            return _replace(c, bits=w_value, resolution_bits=w_value)
        if r is p.Req.SET_RESOLUTION:
            p.check_resolution(w_value, c.bits)
            return _replace(c, resolution_bits=w_value)
        field, decode, low, high, unit = _NUMERIC[r]
        v = decode(data)
        if not low <= v <= high:
            raise self._refuse(req, f"{field} {v} {unit}")
        return _replace(c, **{field: v})

    # ------------------------------------------------------------------------ bulk-IN

    def _make_batch(self) -> None:
        cfg = self._armed_cfg
        assert cfg is not None
        n_ch = len(cfg.channels)
        rec = p.segment_dtype(n_ch, cfg.record_length, cfg.bits)
        count = max(1, min(self._end - self._next, self.batch_bytes // rec.itemsize))
        first = self._next
        cap = self.source.capture(first, count, self.capture_config(cfg))
        codes = np.asarray(cap.codes)
        if codes.shape != (count, n_ch, cfg.record_length):
            raise ValueError(f"SegmentSource returned codes {codes.shape}, expected "
                             f"{(count, n_ch, cfg.record_length)}")
        recs = np.empty(count, dtype=rec)      # every field is written below (the header is packed)
        over = write_samples(recs["data"], codes, np.asarray(cap.overrange, dtype=bool), cfg)
        recs["magic"] = p.MAGIC
        recs["version"] = p.VERSION
        recs["bits"] = cfg.bits
        recs["mask"] = cfg.channel_mask
        recs["overrange"] = p.overrange_flags(over)
        recs["index"] = np.arange(first, first + count, dtype=np.uint32)
        recs["n_samples"] = cfg.record_length
        t_s = np.asarray(cap.trigger_time_s, dtype=np.float64)
        recs["trigger_time_ns"] = np.rint(t_s * 1e9).astype(np.uint64)
        mv = recs.view(np.uint8).data   # the records' bytes, no copy
        # payloads first: the header's crc covers the payload crc's field (bytes 24..27)
        recs["payload_crc32"] = p.payload_crc32s(mv, rec.itemsize, count)
        recs["header_crc32"] = p.header_crc32s(mv, rec.itemsize, count)
        # the capture of the batch's last segment must be over before it can be served
        record_s = cfg.record_length / cfg.sample_rate_hz
        self.clock.advance_to(float(t_s.max()) + record_s)
        new_captured = max(self.segments_captured, first + count)
        if new_captured > self.segments_captured:
            fresh = slice(max(0, self.segments_captured - first), count)
            self.overrange_count += int(over[fresh].sum())
            self.segments_captured = new_captured
        self.state = p.State.DONE if self.segments_captured >= cfg.segments else p.State.CAPTURING
        self.max_batch_segments = max(self.max_batch_segments, count)
        self._batch, self._batch_pos = mv, 0
        self._next = first + count

    def handle_bulk_in(self, ep, buf):
        if ep != p.EP_DATA_IN:
            raise usb_stall(f"digitizer bulk-IN 0x{ep:02x}")
        n_out = 0
        want = len(buf)
        while n_out < want:
            if self._batch is None or self._batch_pos >= len(self._batch):
                if self._next >= self._end:
                    break
                self._make_batch()
            assert self._batch is not None
            k = min(want - n_out, len(self._batch) - self._batch_pos)
            buf[n_out:n_out + k] = self._batch[self._batch_pos:self._batch_pos + k]
            self._batch_pos += k
            n_out += k
        if self._batch is not None and self._batch_pos >= len(self._batch) and self._next >= self._end:
            self._batch = None
        if n_out == 0:
            # nothing requested: a real device NAKs and the host's transfer times out
            raise usb_timeout("digitizer bulk-IN with no READ_SEGMENTS pending")
        self.segments_sent = self._next  # segments pulled into the stream so far
        self.clock.advance(n_out / self.usb_rate_bytes_s)
        return n_out

    def handle_clear_halt(self, ep):
        self._batch, self._next, self._end = None, 0, 0

    def handle_reset(self):
        self._reset_acquisition()


#: requests that change the configuration (refused while armed)
_SETTINGS = frozenset({p.Req.SET_CHANNELS, p.Req.SET_SAMPLE_RATE, p.Req.SET_RECORD_LENGTH, p.Req.SET_SEGMENTS,
                       p.Req.SET_FORMAT, p.Req.SET_RANGE, p.Req.SET_RESOLUTION, p.Req.SET_BANDWIDTH})
#: numeric settings: request -> (Config field, data-stage decoder, lowest, highest, unit)
_NUMERIC = {
    p.Req.SET_SAMPLE_RATE: ("sample_rate_hz", p.dec_u64, SAMPLE_RATE_MIN_HZ, SAMPLE_RATE_MAX_HZ, "Hz"),
    p.Req.SET_RECORD_LENGTH: ("record_length", p.dec_u32, 1, RECORD_LENGTH_MAX, "samples"),
    p.Req.SET_SEGMENTS: ("segments", p.dec_u32, 1, SEGMENTS_MAX, "segments"),
    p.Req.SET_RANGE: ("input_range_mv", p.dec_u32, RANGE_MV_MIN, RANGE_MV_MAX, "mV"),
    p.Req.SET_BANDWIDTH: ("bandwidth_hz", p.dec_u64, 0, p.MAX_BANDWIDTH_HZ, "Hz"),
}


def _replace(c: p.Config, **kw) -> p.Config:
    d = c.__dict__.copy()
    d.update(kw)
    return p.Config(**d)


def decimation_filter(sample_rate_hz: float, core_rate_hz: float, stopband_db: float) -> BeatFilter | None:
    """The decimation filter of a record at ``sample_rate_hz`` from a core at ``core_rate_hz`` (None at
    the core's own rate: no decimation, the analogue front end is the only anti-alias filter)."""
    fs = float(sample_rate_hz)
    if core_rate_hz / fs < 2.0 - 1e-9:
        return None
    filt = DecimationFilter(stopband_db)
    return BeatFilter(response=lambda f: filt.gain(f, fs), passband_hz=PASSBAND_FRACTION * fs)
