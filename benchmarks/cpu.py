"""Pinning a benchmark to one CPU, so that its timings do not share a core with other work. Importing this module
(before numpy) also gives numpy and torch one BLAS thread."""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"


def pin(cpu: int) -> None:
    """Run this process on `cpu` (-1: the first CPU it may use); a CPU it may not use is a one-line error."""
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if not allowed:
        return
    cpu = allowed[0] if cpu < 0 else cpu
    if cpu not in allowed:
        raise SystemExit(f"error: --cpu {cpu} is not one of this process's CPUs {allowed}")
    os.sched_setaffinity(0, {cpu})
