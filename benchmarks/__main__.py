"""``python -m benchmarks``: the performance and accuracy report (see benchmarks/report.py)."""

import os

# One BLAS thread before numpy loads: every figure of the report is per core, and the estimator
# ladder's timings (benchmarks/speed_vs_error.py) are defined that way.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from benchmarks.report import main  # noqa: E402

raise SystemExit(main())
