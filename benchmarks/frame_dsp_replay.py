"""The frame DSP alone on a recorded full CAL frame: the batches a scan hands its DSP, replayed.

``record`` runs the full CAL frame of benchmarks/frame.py (12,288 pixels, 10 averages, default config,
embedded simulated bench) pinned to one core, so that the DSP runs in this process, and saves every
batch ``FrameDsp.process`` receives (records, LSB, the DSP's fields) under ``--dir``. ``time`` loads
them and runs ``process`` over all of them (the compiled kernels loaded first, as the scan's DSP
workers have them): process CPU seconds (best of ``--repeat``), the points, and a digest of every result
field; ``--save`` keeps the results for ``compare``, which prints how two runs' results differ
(flags and counts exactly, the floats by their largest difference). For an A/B against another tree,
record once, then alternate the trees on PYTHONPATH (the machine is shared):

    python benchmarks/frame_dsp_replay.py record --dir /tmp/frame_dsp
    for t in /tmp/main $PWD; do PYTHONPATH=$t OPENBLAS_NUM_THREADS=1 python benchmarks/frame_dsp_replay.py time --dir /tmp/frame_dsp; done
    python benchmarks/frame_dsp_replay.py compare a.npz b.npz
"""

from __future__ import annotations

import argparse
import glob
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

FIELDS = ("present", "valid", "range_m", "velocity_mps", "snr_db", "intensity_v", "flags")


def record(out_dir: str, averages: int = 10) -> None:
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})     # one core: no DSP pool, process() runs here
    from lidard.dsp.frame import FrameDsp
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import frame

    Path(out_dir).mkdir(parents=True, exist_ok=True)
    orig = FrameDsp.process
    count = [0]

    def keep(self, beat, lsb_v=1.0, **kw):
        if any(isinstance(v, np.ndarray) for v in kw.values()):
            raise SystemExit("this benchmark replays the plain front end (no MZI or Q channel)")
        i = count[0]
        count[0] += 1
        np.save(f"{out_dir}/b{i:04d}.npy", np.asarray(beat))
        with open(f"{out_dir}/b{i:04d}.json", "w") as f:
            json.dump({"dsp": self.to_record(), "lsb_v": lsb_v}, f)
        return orig(self, beat, lsb_v, **kw)

    FrameDsp.process = keep     # type: ignore[method-assign]
    out = frame.run_frame(averages=averages)
    print(f"recorded {count[0]} batches of {out['pixels']} pixels ({out['points']} points) in {out_dir}")


def _load(in_dir: str):
    from lidard.dsp.frame import FrameDsp

    files = sorted(glob.glob(f"{in_dir}/b*.npy"))
    if not files:
        raise SystemExit(f"no recorded batches in {in_dir} (run: record --dir {in_dir})")
    with open(files[0][:-4] + ".json") as f:
        meta = json.load(f)
    return FrameDsp.from_record(meta["dsp"]), float(meta["lsb_v"]), [np.load(p) for p in files]


def timed(in_dir: str, repeat: int = 1, save: str | None = None) -> dict:
    from lidard.dsp.spectrum.jit import kernels

    kernels()
    dsp, lsb, batches = _load(in_dir)
    dsp.process(batches[-1], lsb)      # tables and scratch buffers built, as in a running worker
    best, res = np.inf, []
    for _ in range(repeat):
        t0 = time.process_time()
        res = [dsp.process(b, lsb) for b in batches]
        best = min(best, time.process_time() - t0)
    cat = {f: np.concatenate([getattr(r, f) for r in res]) for f in FIELDS}
    h = hashlib.sha256()
    for f in FIELDS:
        h.update(np.ascontiguousarray(cat[f]).tobytes())
    if save:
        np.savez(save, **cat)
    return {"cpu_s": best, "pixels": int(sum(len(b) for b in batches)), "points": int(cat["present"].sum()),
            "valid": int(cat["valid"].sum()), "digest": h.hexdigest()[:16]}


def compare(a_path: str, b_path: str) -> None:
    a, b = np.load(a_path), np.load(b_path)
    for f in FIELDS:
        x, y = a[f], b[f]
        if x.dtype.kind in "biu":
            print(f"{f}: {int(np.count_nonzero(x != y))} entries differ")
        else:
            fin = np.isfinite(x) & np.isfinite(y)
            d = np.abs(x[fin] - y[fin])
            print(f"{f}: finite/non-finite mismatches {int(np.count_nonzero(np.isfinite(x) != np.isfinite(y)))}, "
                  f"largest difference {d.max() if d.size else 0.0:.3g}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--dir", required=True)
    r.add_argument("--averages", type=int, default=10)
    t = sub.add_parser("time")
    t.add_argument("--dir", required=True)
    t.add_argument("--repeat", type=int, default=1)
    t.add_argument("--save", default=None, help="keep the results (npz) for compare")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args(argv)
    if args.cmd == "record":
        record(args.dir, args.averages)
    elif args.cmd == "time":
        out = timed(args.dir, args.repeat, args.save)
        print(f"DSP CPU {out['cpu_s']:.3f} s over {out['pixels']} pixels; {out['points']} points, "
              f"{out['valid']} valid; digest {out['digest']}")
    else:
        compare(args.a, args.b)


if __name__ == "__main__":
    main()
