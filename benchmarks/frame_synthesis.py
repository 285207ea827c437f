"""The bench's beat synthesis of a CAL frame, replayed on one thread: CPU per sample and a digest.

A region of the default CAL frame (``--rows``, all 128 columns, 10 averages, the default config's
band) is scanned once on the embedded simulated bench while every call the bench makes to
``sim_devices.world.synth.synthesize`` (one per part of a read, as
sim_devices.world.synth_parallel cuts it) is recorded with its generator's state. The calls are
then replayed in this thread ``--repeats`` times (after one warm-up) and the best CPU time
(time.process_time) is printed per record sample, with a digest of the replayed records (codes and
overrange flags, order-independent): two trees that give the same digest synthesized the same
records. numba is loaded first, as the frame's DSP loads it (the compiled kernels run).

Unlike the frame's thread-CPU stage figure (benchmarks/frame.py), this is one thread with nothing
beside it in the process, so it moves much less with the machine's load.

    python benchmarks/frame_synthesis.py [--rows 40:46] [--repeats 5] [--json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import threading
import time

import numpy as np


def record_calls(rows: tuple[int, int]) -> list:
    """(traj, adc, t_start, hits, generator state, keyword arguments) of every synthesize call of one
    region scan of the CAL frame, in completion order."""
    import sim_devices.world.synth_parallel as parallel
    from lidard.config import CONFIG_DIR, load_config
    from lidard.instrument import ScanRequest, open_instrument

    calls: list = []
    lock = threading.Lock()
    plain = parallel.synthesize

    def recording(traj, adc, t0, hits, rng=None, **kw):
        state = None if rng is None else rng.bit_generator.state
        with lock:
            calls.append((traj, adc, t0, hits, state, kw))
        return plain(traj, adc, t0, hits, rng=rng, **kw)

    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, scene_path=str(CONFIG_DIR / "scenes" / "cal_letters.toml"), bench="embedded")
    try:
        cal = inst.linearize()
        parallel.synthesize = recording
        req = ScanRequest(pattern="roi", rows=rows, cols=(0, 128), averages=10, max_range_m=2.0)
        inst.run_scan(req, lambda p: None, threading.Event(), cal)
    finally:
        parallel.synthesize = plain
        inst.close()
    return calls


def replay(calls: list, repeats: int) -> tuple[float, str]:
    """(best CPU seconds of one replay of every call, digest of the records)."""
    from sim_devices.world.synth import synthesize

    def once(digests: list | None) -> float:
        c = time.process_time()
        for traj, adc, t0, hits, state, kw in calls:
            rng = np.random.default_rng()
            if state is not None:
                rng.bit_generator.state = state
            out = synthesize(traj, adc, t0, hits, rng=rng, **kw)
            if digests is not None:
                digests.append(hashlib.sha256(out.beat.tobytes() + out.overrange.tobytes()).hexdigest())
        return time.process_time() - c

    digests: list = []
    once(digests)
    best = min(once(None) for _ in range(repeats))
    return best, hashlib.sha256("".join(sorted(digests)).encode()).hexdigest()[:16]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", default="40:46", help="rows a:b of the 128 x 128 CAL frame to scan")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    r0, r1 = (int(v) for v in a.rows.split(":"))
    calls = record_calls((r0, r1))
    try:
        import numba  # noqa: F401  (the frame's DSP has it loaded: the compiled kernels run)
    except ImportError:
        pass
    samples = sum(int(np.asarray(c[2]).size) * int(c[1].n_samples) for c in calls)
    cpu, digest = replay(calls, a.repeats)
    out = {"rows": [r0, r1], "calls": len(calls), "samples": samples, "cpu_s": cpu,
           "ns_per_sample": cpu / max(samples, 1) * 1e9, "digest": digest}
    if a.json:
        print(json.dumps(out))
        return
    print(f"{out['calls']} synthesize calls, {samples / 1e6:.2f} M samples: {cpu:.3f} s CPU, "
          f"{out['ns_per_sample']:.2f} ns a sample (best of {a.repeats}); records digest {digest}")


if __name__ == "__main__":
    main()
