"""``lidarctl linearize``: run the chirp linearization (iterative learning control, dissertation §2.2)
on the daemon or, with ``--sim``, on an embedded bench, and print or plot the RMS frequency error of
each iteration.

``--plot`` needs matplotlib, which is a main dependency of lidard (``pip install -e .`` brings it).
"""

from __future__ import annotations

from . import base, output
from .base import CliError
from .client import client, daemon_opts, refuse_sim_only


def add_parser(sub) -> None:
    sp = sub.add_parser("linearize", help="run the chirp linearization (ILC) and report its RMS error")
    daemon_opts(sp, sim=True)
    sp.add_argument("--plot", default=None, metavar="FILE.png",
                    help="also plot RMS frequency error (Hz) against ILC iteration to this PNG")
    sp.set_defaults(fn=cmd_linearize)


def cmd_linearize(args) -> int:
    refuse_sim_only(args, "--config", "--data-dir", "--no-cal-cache")
    if args.sim:
        from .embedded import embedded
        with embedded(args) as (worker, store, inst):
            cal = worker.submit_calibration().result()
        iterations, reduction, converged = cal.iterations, cal.reduction, bool(cal.converged)
    else:
        with client(args) as c:
            body = c.request("POST", "/calibration/linearize", timeout=None).json()
        iterations, reduction, converged = body["iterations"], body["reduction"], body["converged"]
    its = [{"up_rms_hz": float(it["up_rms_hz"]), "down_rms_hz": float(it["down_rms_hz"])} for it in iterations]
    if args.plot:
        plot_linearization(its, args.plot)
    if args.json:
        output.emit_json({"iterations": its, "reduction": {k: float(v) for k, v in reduction.items()},
                          "converged": converged})
        return 0
    print(output.table([[i, f"{it['up_rms_hz']:.4e}", f"{it['down_rms_hz']:.4e}"] for i, it in enumerate(its)],
                       ["ITER", "UP RMS (Hz)", "DOWN RMS (Hz)"]))
    print("reduction: " + ", ".join(f"{k} {v:.3g}x" for k, v in reduction.items())
          + ("" if converged else " (not converged)"))
    return 0


def _pyplot():
    try:
        import matplotlib
    except ImportError:
        raise CliError("--plot needs matplotlib, a dependency of lidard: reinstall with "
                       "`pip install -e .` (or `pip install 'matplotlib>=3.8,<4'`)") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_linearization(its: list[dict[str, float]], path: str) -> None:
    import io
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    n = range(len(its))
    ax.semilogy(n, [it["up_rms_hz"] for it in its], "o-", label="up-ramp")
    ax.semilogy(n, [it["down_rms_hz"] for it in its], "s-", label="down-ramp")
    ax.set_xlabel("ILC iteration")
    ax.set_ylabel("RMS frequency error (Hz)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    base.write_bytes_atomic(path, buf.getvalue())
