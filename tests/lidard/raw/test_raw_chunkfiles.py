"""The direct chunk-file reader (lidard.raw.chunkfiles) against zarr's own read, on captures written
by RawWriter now (bit-shuffled samples) and as captures were written before (byte-shuffled), and its
fall-back to zarr for a layout it does not know."""

from __future__ import annotations

import os

import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, GzipCodec

from lidard.raw import RawCapture, RawCaptureError, reprocess
from lidard.raw import capture as capture_mod
from lidard.raw.chunkfiles import ChunkFiles
from lidard.raw.points import frame_points

ARRAYS = ("segments", "overrange", "trigger_time_ns", "t_s", "pixels", "directions")


def _zarr_rows(path, name, a, b):
    return np.asarray(zarr.open_group(str(path), mode="r")[name][a:b])


def _ranges(n, rows):
    """Row ranges that start and end inside chunks, on chunk edges, span several chunks, the whole."""
    return [(0, n), (0, 1), (n - 1, n), (1, n - 1), (rows - 1, rows + 1), (rows, 2 * rows), (3, min(n, 2 * rows + 3))]


def _direct_points(syn):
    res = syn.dsp.process(syn.channel("beat"), 2.0 / 2**16)
    clipped = syn.overrange.reshape(len(syn.pixels), -1).any(axis=1)
    return frame_points(res, syn.pixels, syn.t_s, syn.directions, clipped, syn.dsp.measurement_delay_s(syn.averages))


def test_every_array_reads_as_zarr_reads_it_on_every_row_range(make_capture):
    # 3 channels, 42 pixels in chunks of 5 (the last one short: its chunk file is stored whole)
    syn = make_capture("c.zarr", n_pix=42, chunk_pixels=5, with_mzi=True, with_mzi_q=True, batch=4)
    for name in ARRAYS:
        files = ChunkFiles.open(syn.path / name)
        assert files is not None, name
        n = zarr.open_group(str(syn.path), mode="r")[name].shape[0]
        for a, b in _ranges(n, files.rows_per_chunk):
            got, ref = files.read(a, b), _zarr_rows(syn.path, name, a, b)
            assert got.dtype == ref.dtype and got.shape == ref.shape and np.array_equal(got, ref), (name, a, b)
    assert np.array_equal(ChunkFiles.open(syn.path / "segments").read(0, 84), syn.segments)


def test_an_absent_chunk_file_reads_as_the_fill_value(make_capture):
    # zarr writes no chunk that holds only the fill value: overrange is zero after the first chunk
    syn = make_capture("c.zarr", n_pix=40, chunk_pixels=8)
    assert not (syn.path / "overrange" / "c" / "2").exists() and (syn.path / "overrange" / "c" / "0").exists()
    got = ChunkFiles.open(syn.path / "overrange").read(0, 80)
    assert np.array_equal(got, syn.overrange) and got[16:].max() == 0 and got[3] == 1


def test_a_capture_written_byte_shuffled_reads_and_replays_as_before(make_capture, monkeypatch):
    monkeypatch.setattr(capture_mod, "_COMPRESSOR", BloscCodec(cname="lz4", clevel=1, shuffle="shuffle"))
    syn = make_capture("old.zarr", n_pix=40, chunk_pixels=16)
    meta = zarr.open_group(str(syn.path), mode="r")["segments"].metadata.to_dict()
    assert [c["configuration"]["shuffle"] for c in meta["codecs"] if c["name"] == "blosc"] == ["shuffle"]
    cap = RawCapture(syn.path)
    assert np.array_equal(cap.chunks(0, cap.n_chunks).segments, syn.segments)
    assert np.array_equal(reprocess(syn.path, map_fn=map).points, _direct_points(syn))


def test_new_captures_are_bit_shuffled(capture):
    meta = zarr.open_group(str(capture.path), mode="r")["segments"].metadata.to_dict()
    assert [c["configuration"]["shuffle"] for c in meta["codecs"] if c["name"] == "blosc"] == ["bitshuffle"]


def test_a_layout_it_does_not_know_is_read_through_zarr(make_capture, monkeypatch):
    monkeypatch.setattr(capture_mod, "_COMPRESSOR", GzipCodec(level=1))
    syn = make_capture("gz.zarr", n_pix=40, chunk_pixels=16)
    assert ChunkFiles.open(syn.path / "segments") is None
    assert ChunkFiles.open(syn.path / "pixels") is not None
    cap = RawCapture(syn.path)
    assert np.array_equal(cap.chunks(0, cap.n_chunks).segments, syn.segments)
    assert cap._files["segments"] is None
    assert np.array_equal(reprocess(syn.path, map_fn=map).points, _direct_points(syn))


def test_a_damaged_chunk_file_is_named(capture):
    (capture.path / "segments" / "c" / "1" / "0" / "0").write_bytes(b"not a blosc frame")
    cap = RawCapture(capture.path)
    cap.chunk(0)
    with pytest.raises(RawCaptureError, match=r"segments rows 32\.\.63 unreadable"):
        cap.chunk(1)


def test_a_task_asks_the_kernel_for_the_next_tasks_sample_files(make_capture, monkeypatch):
    # 40 pixels in chunks of 4 (10 chunks), tasks of 2 chunks: task 1 reads chunks 2, 3 and advises 4, 5;
    # the last task advises nothing (no chunk beyond the capture)
    from lidard.raw import replay
    syn = make_capture("c.zarr", n_pix=40, chunk_pixels=4)
    advised: list[str] = []
    real = os.posix_fadvise

    def spy(fd, offset, length, advice):
        if advice == os.POSIX_FADV_WILLNEED:
            advised.append(os.path.relpath(os.readlink(f"/proc/self/fd/{fd}"), syn.path))
        return real(fd, offset, length, advice)

    monkeypatch.setattr(os, "posix_fadvise", spy)
    pts = replay.reprocess_task(syn.path, 1, chunks_per_task=2)
    assert advised == ["segments/c/4/0/0", "segments/c/5/0/0"]
    advised.clear()
    replay.reprocess_task(syn.path, 4, chunks_per_task=2)
    assert advised == []
    ref = _direct_points(syn)
    assert np.array_equal(pts, ref[np.isin(ref["row"] * 8 + ref["col"], np.arange(8, 16))])
