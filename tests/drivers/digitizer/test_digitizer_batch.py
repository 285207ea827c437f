"""A read's worth of segments at once: the simulator's batch framing against the one-segment encoder
(whose bytes are the golden vectors of docs/protocols/digitizer.md), the driver's header columns
against the one-segment decoder, and the driver's crc checks naming the damaged segment."""

import numpy as np
import pytest
import usb.core

from drivers.digitizer import protocol as p
from drivers.digitizer.driver import DigitizerDataError, DigitizerDriver
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer
from sim_devices.usb.backend import SimUsbBackend


class NoiseSource:
    """Segment k: codes drawn from a generator seeded by k (a re-read gives the same), trigger k at
    k * 100 us + 7 ns; segments listed in ``over`` flagged overrange on channel 0."""

    def __init__(self, over=()):
        self.over = set(over)

    def expected(self, first, count, cfg):
        n_ch = len(cfg.channels)
        codes = np.stack([np.random.default_rng(k).integers(-2000, 2000, (n_ch, cfg.record_length))
                          for k in range(first, first + count)]).astype(np.int16)
        over = np.zeros((count, n_ch), bool)
        over[[k - first for k in self.over if first <= k < first + count], 0] = True
        return np.arange(first, first + count) * 100e-6 + 7e-9, codes, over

    def capture(self, first, count, cfg):
        return CapturedSegments(*self.expected(first, count, cfg))


def _rig(batch_bytes=64 * 1024, over=(2, 5)):
    src = NoiseSource(over=over)
    sim = SimDigitizer(VirtualClock(), src, batch_bytes=batch_bytes)
    dev = usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=SimUsbBackend([sim]))
    drv = DigitizerDriver(dev, timeout_ms=200, retries=0, chunk_bytes=48 * 1024)
    cfg = drv.configure(channels=("beat", "mzi"), sample_rate_hz=100e6, record_length=300, segments=40,
                        bits=16, input_range_v=0.5)
    drv.arm()
    return drv, dev, sim, src, cfg


def _raw_stream(dev, first, count, nbytes):
    dev.ctrl_transfer(p.REQTYPE_OUT, int(p.Req.READ_SEGMENTS), 0, 0, p.enc_read_segments(first, count), 200)
    out = b""
    while len(out) < nbytes:
        out += bytes(dev.read(p.EP_DATA_IN, nbytes - len(out), 200))
    return out


def test_batch_bytes_are_the_one_segment_encoder_s():
    drv, dev, sim, src, cfg = _rig(batch_bytes=8 * 1024)     # several device batches per read
    first, count = 3, 30
    size = p.segment_bytes(2, 300, 16)
    wire = _raw_stream(dev, first, count, count * size)
    t, codes, over = src.expected(first, count, sim.capture_config())
    expect = b"".join(p.encode_segment(first + i, int(round(t[i] * 1e9)), cfg.channel_mask, 16,
                                       int(p.overrange_flags(over[i:i + 1])[0]), codes[i])
                      for i in range(count))
    assert len(wire) == len(expect) and wire == expect
    assert any(over[:, 0])          # the overrange bits are in the bytes compared


def test_header_columns_equal_the_one_segment_decoder():
    drv, dev, sim, src, cfg = _rig()
    headers, samples = drv.read_segments(0, 12, cfg)
    assert isinstance(headers, p.SegmentHeaders) and len(headers) == 12
    size = p.segment_bytes(2, 300, 16)
    drv2, dev2, _, _, _ = _rig()
    wire = _raw_stream(dev2, 0, 12, 12 * size)
    decoded = [p.decode_segment(wire[i * size:(i + 1) * size]) for i in range(12)]
    assert list(headers) == [h for h, _, _ in decoded]
    assert headers[5] == decoded[5][0] and headers[-1] == decoded[11][0]
    assert list(headers[2:4]) == [decoded[2][0], decoded[3][0]]
    assert np.array_equal(headers.trigger_time_ns, [h.trigger_time_ns for h, _, _ in decoded])
    assert headers.overrange.tolist() == [1 if i in (2, 5) else 0 for i in range(12)]
    assert np.array_equal(samples, np.stack([s for _, s, _ in decoded]))
    assert np.array_equal(p.header_column(headers, "overrange"), p.header_column(list(headers), "overrange"))


def test_header_columns_do_not_alias_the_transfer_buffer():
    drv, dev, sim, src, cfg = _rig()
    headers, _ = drv.read_segments(0, 4, cfg)       # one transfer: parsed in the driver's buffer
    kept = headers.trigger_time_ns.copy()
    drv.read_segments(4, 4, cfg)                    # the same buffer, other segments
    assert np.array_equal(headers.trigger_time_ns, kept) and headers.index.tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize("offset, what", [(p.HEADER_LEN + 7, "payload"), (17, "header")])
def test_a_damaged_segment_is_named(monkeypatch, offset, what):
    drv, dev, sim, src, cfg = _rig()
    size = p.segment_bytes(2, 300, 16)
    real = sim._make_batch

    def damaged():
        real()
        start = sim._next - len(sim._batch) // size
        if start <= 6 < sim._next:                  # the batch holding segment 6: one bit flipped
            buf = bytearray(sim._batch)
            buf[(6 - start) * size + offset] ^= 0x40
            sim._batch = memoryview(bytes(buf))
    monkeypatch.setattr(sim, "_make_batch", damaged)
    with pytest.raises(DigitizerDataError, match=f"segment 6 {what} crc32 mismatch"):
        drv.read_segments(0, 10, cfg)


def test_segment_headers_refuse_ragged_columns():
    cols = dict(index=[0, 1], trigger_time_ns=[0, 1], n_samples=[2, 2], channel_mask=[1, 1], bits=[16, 16],
                overrange=[0, 0], payload_crc32=[5])
    with pytest.raises(ValueError, match="one length"):
        p.SegmentHeaders(**cols)
    with pytest.raises(TypeError, match="columns"):
        p.SegmentHeaders(index=[0])
