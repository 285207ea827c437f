"""One pixel's range spectra from a raw capture, with the CFAR threshold and the detections.

What the scan DSP saw for that pixel (dissertation §2.1 range FFT, §4.4.3 detection): per ramp
(up, down) the power spectrum averaged over the pixel's segments (with phase-noise compensation,
§2.3, the composite compensated spectrum), the OS-CFAR threshold ``alpha * noise`` per bin, the
bins CFAR detected and the points the pairing made of them. :func:`plot_pixel_spectrum` draws it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..dsp.detect.cfar import cfar_detect_with
from ..dsp.detect.os_cfar import _noise_os   # the kernel cfar_detect_with thresholds with (no public twin)
from ..dsp.ranging.iqbalance import correct, ramp_volts
from ..dsp.pnframe import compensator_for
from ..dsp.spectrum.window import get_window
from ..outputs.schema import POINT_DTYPE, POINT_NAMES
from .capture import PixelNotRecorded, RawCapture
from ..dsp.spectrum.jit import follow
from .replay import ReplayDsp, ReprocessSettings, replay_dsp

# CfarSettings defaults, which FrameDsp uses (n_ref cells in total, n_guard per side)
_N_REF, _N_GUARD = 16, 2


@dataclass(frozen=True)
class PixelSpectrum:
    row: int
    col: int
    range_m: np.ndarray            # (n_bins,) range of every spectrum bin
    power: dict[str, np.ndarray]   # "up"/"down": |X|^2 averaged over the pixel's segments, V^2
    threshold: dict[str, np.ndarray]
    gate: tuple[int, int]          # (first, last) bin searched by CFAR
    detections: list[dict[str, Any]]
    points: np.ndarray             # the pixel's point records (POINT_DTYPE)
    dsp: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (lists), for ``lidarctl spectrum --json`` and the API."""
        return {"row": self.row, "col": self.col, "range_m": self.range_m.tolist(),
                "power_v2": {k: v.tolist() for k, v in self.power.items()},
                "threshold_v2": {k: v.tolist() for k, v in self.threshold.items()},
                "gate_bins": list(self.gate), "detections": self.detections, "dsp": self.dsp,
                "points": [{k: p[k].item() for k in p.dtype.names} for p in self.points]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PixelSpectrum:
        """Inverse of :meth:`to_dict` (what a client gets from ``GET /scans/{id}/spectrum``)."""
        pts = np.zeros(len(d["points"]), POINT_DTYPE)
        for i, p in enumerate(d["points"]):
            for k in POINT_NAMES:
                if k in p:          # a server older than a field (e.g. ``flags``) leaves it 0
                    pts[i][k] = p[k]
        return cls(row=int(d["row"]), col=int(d["col"]), range_m=np.asarray(d["range_m"], np.float64),
                   power={k: np.asarray(v, np.float64) for k, v in d["power_v2"].items()},
                   threshold={k: np.asarray(v, np.float64) for k, v in d["threshold_v2"].items()},
                   gate=tuple(d["gate_bins"]), detections=list(d["detections"]), points=pts, dsp=dict(d["dsp"]))


def _ramp_power(replay: ReplayDsp, beat: np.ndarray, mzi: np.ndarray | None, mzi_q: np.ndarray | None,
                start: int) -> np.ndarray:
    """(1, n_bins) averaged power of one ramp as the frame DSP computes it before CFAR."""
    d = replay.dsp
    a, n, r = d.offset, d.n_used, d.ramp_samples
    # an I/Q capture's beat is the corrected complex I + jQ; its down ramp in the up ramp's sign
    b = ramp_volts(beat[..., start:start + r], replay.lsb_v, iq=d.iq, down=bool(start))
    if mzi is None or replay.mzi_delay_s is None:
        spec = d.rfft(b[..., a:a + n])
    else:
        comp = compensator_for(d, replay.mzi_delay_s)
        q = None if mzi_q is None else mzi_q[..., start:start + r].astype(np.float64) * replay.lsb_v
        ramps = comp.prepare(b, mzi[..., start:start + r].astype(np.float64) * replay.lsb_v, a, n, mzi_q=q)
        spec, _ = ramps.composite_spectrum(get_window(d.window, n), d.rfft.n_fft)
    return (spec.real**2 + spec.imag**2).mean(axis=1)


def pixel_spectrum(raw_path: str | Path, row: int, col: int,
                   settings: ReprocessSettings | None = None) -> PixelSpectrum:
    """Spectra, CFAR threshold, detections and points of pixel (row, col) of a capture."""
    cap = RawCapture(raw_path)
    replay = replay_dsp(cap.attrs, settings)
    i = cap.pixel_index(row, col)
    ci = i // cap.chunk_pixels
    if ci >= cap.n_chunks:
        raise PixelNotRecorded(f"raw capture {cap.path}: pixel ({row}, {col}) is past the committed chunks")
    chunk = cap.chunk(ci)
    k = i - ci * cap.chunk_pixels
    s0, s1 = k * cap.averages, (k + 1) * cap.averages
    one = dataclasses.replace(chunk, segments=chunk.segments[s0:s1], overrange=chunk.overrange[s0:s1],
                              trigger_time_ns=chunk.trigger_time_ns[s0:s1], pixels=chunk.pixels[k:k + 1],
                              directions=chunk.directions[k:k + 1], t_s=chunk.t_s[k:k + 1])
    d = replay.dsp
    if d.iq:    # the coherent receiver: I and Q, the recorded imbalance removed (lidard.dsp.ranging.iqbalance)
        beat = correct(one.channel("beat_i", cap.channels, cap.averages),
                       one.channel("beat_q", cap.channels, cap.averages), d.iq_gain, d.iq_phase_rad)
    else:
        beat = one.channel("beat", cap.channels, cap.averages)
    mzi, mzi_q = replay.monitor(one, cap.channels, cap.averages)
    gate = d.bin_range
    power, threshold, dets = {}, {}, []
    with follow(replay.dsp_path):      # the scan's DSP path, as the replay's points take it
        for name, start in (("up", 0), ("down", d.ramp_samples)):
            p = _ramp_power(replay, beat, mzi, mzi_q, start)
            # p averages the pixel's records: the detector's noise model is Gamma(records), as the scan's
            det = cfar_detect_with(p, replace(d.cfar, records=cap.averages))
            noise, alpha = _noise_os(p, _N_REF // 2, _N_GUARD, d.ramp_pfa, None, exact=True,
                                     records=cap.averages)   # drawn at every bin
            power[name], threshold[name] = p[0], (alpha * noise)[0]
            for j in np.flatnonzero(det.valid[0]):
                b = int(det.index[0, j])
                dets.append({"ramp": name, "bin": b, "range_m": float(d.rfft.range_m[b]),
                             "snr_db": float(det.snr_db[0, j]), "harmonic": bool(det.harmonic[0, j]),
                             "unresolved": bool(det.unresolved[0, j])})
    return PixelSpectrum(row=int(row), col=int(col), range_m=d.rfft.range_m, power=power, threshold=threshold,
                         gate=(int(gate[0]), int(gate[1])), detections=dets,
                         points=replay.points(one, cap.channels, cap.averages), dsp=replay.meta())


def plot_pixel_spectrum(spec: PixelSpectrum, path: str | Path) -> Path:
    """Both ramps' spectra (dB), CFAR threshold, the searched gate, detections and point ranges; PNG."""
    import matplotlib
    matplotlib.use("Agg")           # files only: no display needed (a daemon, CI)
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    lo, hi = spec.gate
    x = spec.range_m
    floor = 1e-30   # keep log10 finite on an all-zero bin
    for ax, name in zip(axes, ("up", "down")):
        ax.plot(x, 10 * np.log10(spec.power[name] + floor), lw=0.8, label="power (averaged)")
        ax.plot(x, 10 * np.log10(spec.threshold[name] + floor), "--", lw=0.8, label="OS-CFAR threshold")
        ax.axvspan(x[lo], x[min(hi, len(x) - 1)], color="0.9", zorder=-1, label="searched gate")
        for det in (d for d in spec.detections if d["ramp"] == name):
            b = det["bin"]
            ax.plot(x[b], 10 * np.log10(spec.power[name][b] + floor), "rv", ms=7)
        ax.set_ylabel(f"{name} ramp, dB V$^2$")
        ax.grid(alpha=0.3)
    for p in spec.points:
        axes[0].axvline(float(p["range"]), color="g", lw=0.8, alpha=0.7)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"pixel ({spec.row}, {spec.col}): {len(spec.points)} point(s), "
                      f"estimator {spec.dsp['estimator']}, pfa {spec.dsp['pfa']:g}, window {spec.dsp['window']}")
    axes[1].set_xlabel("range (m)  [beat frequency x c / 2 gamma]")
    axes[1].set_xlim(0, x[min(hi + 5, len(x) - 1)])
    out = Path(path)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
