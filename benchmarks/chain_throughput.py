"""The detection chain's throughput against a plain FFT + argmax (issue 18: >= 50 % at N = 512).

"Chain": :func:`lidard.dsp.chain.measure_peaks`, i.e. the Hann-windowed range FFT, OS-CFAR (the frame
DSP's settings: Pfa 1e-6, up to 2 returns) and the default sub-bin estimator on every detection.
"Plain": a Hann-windowed ``np.fft.rfft`` and an argmax of the power per ramp (the least a range
estimate needs, as the limit kernel of benchmarks/limit.py does). Both on the same batch of ramps
(one real tone per ramp at a random frequency and phase, white noise, 20 dB post-FFT SNR), on one
core (BLAS threads pinned to 1 before numpy loads), CPU time, best of ``repeats``; printed as ramps
per second and the ratio chain / plain (1.0 = as fast as the plain FFT + argmax).

    python benchmarks/chain_throughput.py [--n 512] [--batch 20000] [--repeats 5] [--json]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lidard.dsp.chain import measure_peaks  # noqa: E402
from lidard.dsp.ranging.estimators import DEFAULT_METHOD  # noqa: E402
from lidard.dsp.spectrum.rangefft import RangeFFT  # noqa: E402

FS_HZ = 5e6
CHIRP_RATE_HZ_PER_S = 1.075e14   # 8.6 GHz in 80 us (config/sim.toml)


def make_ramps(n: int, batch: int, snr_db: float = 20.0, seed: int = 0) -> np.ndarray:
    """Real tones, amplitude 1, at 10 .. n/2 - 10 bins, with noise for ``snr_db`` post-FFT SNR."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    f = rng.uniform(10, n / 2 - 10, (batch, 1))
    sigma = np.sqrt(n / (4 * 10 ** (snr_db / 10)))
    return np.cos(2 * np.pi * f * t / n + rng.uniform(0, 2 * np.pi, (batch, 1))) + sigma * rng.standard_normal((batch, n))


def _plain(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    s = np.fft.rfft(x * w, axis=-1)
    return np.argmax(s.real ** 2 + s.imag ** 2, axis=-1)


def best_cpu_s(fn, repeats: int) -> float:
    """Best (least) process CPU time of ``repeats`` calls of ``fn`` (robust to other jobs)."""
    best = np.inf
    for _ in range(repeats):
        c = time.process_time()
        fn()
        best = min(best, time.process_time() - c)
    return best


def run_chain_throughput(n: int = 512, batch: int = 20_000, repeats: int = 5) -> dict:
    """Ramps/s of the chain and of the plain FFT + argmax, their ratio, and the detection rate."""
    x = make_ramps(n, batch)
    rf = RangeFFT(n, FS_HZ, CHIRP_RATE_HZ_PER_S, window="hann")
    w = np.hanning(n + 1)[:-1]
    # OS-CFAR is cfar_detect's default method
    chain = lambda: measure_peaks(rf, x, method=DEFAULT_METHOD, pfa=1e-6, max_detections=2)  # noqa: E731
    res = chain()
    plain = lambda: _plain(x, w)  # noqa: E731
    plain()
    t_chain, t_plain = best_cpu_s(chain, repeats), best_cpu_s(plain, repeats)
    return {"n": n, "batch": batch, "estimator": DEFAULT_METHOD,
            "chain_ramps_per_s": batch / t_chain, "plain_ramps_per_s": batch / t_plain,
            "ratio": t_plain / t_chain, "detected": float(res.detections.valid[:, 0].mean()),
            "chain_ms": 1e3 * t_chain, "plain_ms": 1e3 * t_plain, "stages_ms": _stages_ms(rf, x, repeats)}


def _stages_ms(rf: RangeFFT, x: np.ndarray, repeats: int) -> dict:
    """The chain's stages timed one by one on the same ramps (ms, best of ``repeats``): where it goes."""
    from lidard.dsp.detect.cfar import cfar_detect
    from lidard.dsp.chain import _refine_valid
    from lidard.dsp.spectrum.jit import power

    spec = rf(x)
    p = power(spec)
    gate = np.flatnonzero(rf.gate_mask)
    kw = dict(pfa=1e-6, max_detections=2, bin_range=(int(gate[0]), int(gate[-1])), window=rf.window)
    det = cfar_detect(p, **kw)
    idx = rf.index_to_bin(np.where(det.valid, det.index, 1))
    from lidard.dsp.spectrum.rangefft import check_samples

    # the chain writes its spectrum and power into scratch buffers (lidard.dsp.spectrum.scratch), chunk by chunk
    buf, pbuf = np.empty_like(spec), np.empty_like(p)
    return {"fft_and_power": 1e3 * best_cpu_s(
                lambda: rf.spectrum_of(check_samples(x, rf.n_samples), out=buf, power_out=pbuf), repeats),
            "cfar": 1e3 * best_cpu_s(lambda: cfar_detect(p, **kw), repeats),
            "estimator": 1e3 * best_cpu_s(lambda: _refine_valid(x, idx, det.valid, spec, method=DEFAULT_METHOD,
                                                                  window=rf.window, zero_pad=rf.zero_pad), repeats)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=512)
    ap.add_argument("--batch", type=int, default=20_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    r = run_chain_throughput(a.n, a.batch, a.repeats)
    if a.json:
        print(json.dumps(r))
        return
    print(f"N = {r['n']}, {r['batch']} ramps, one core, CPU time: chain (FFT + OS-CFAR + {r['estimator']}) "
          f"{r['chain_ramps_per_s']:,.0f} ramps/s; plain FFT + argmax {r['plain_ramps_per_s']:,.0f} ramps/s; "
          f"chain / plain = {r['ratio']:.2f} (target >= 0.50: {'MET' if r['ratio'] >= 0.5 else 'NOT MET'}); "
          f"{r['detected']:.1%} of ramps detected")
    st = r["stages_ms"]
    print(f"per {r['batch']} ramps: chain {r['chain_ms']:.1f} ms, plain {r['plain_ms']:.1f} ms; chain stages timed "
          f"alone: FFT and power {st['fft_and_power']:.1f}, CFAR {st['cfar']:.1f}, estimator {st['estimator']:.1f} ms")


if __name__ == "__main__":
    main()
