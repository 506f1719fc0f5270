"""Process-wide numeric runtime settings: native thread pools.

On the 2-vCPU machines this project targets, multi-threaded BLAS and torch kernels are erratic
and often far slower than one thread (measured: a (72000, 3) @ (3, 3) matmul takes 23 ms with
OpenBLAS on 2 threads and 0.5 ms on 1; torch shows the same). Parallelism comes from processes
(trial workers, the render worker) instead, so every entry point pins native pools explicitly.
"""

from __future__ import annotations

import os

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


def configure_threads(n: int = 1) -> None:
    """Limit BLAS/OpenMP/torch thread pools to ``n`` in this process (and its children).

    Environment variables cover libraries not yet loaded and child processes; threadpoolctl and
    ``torch.set_num_threads`` cover the ones already loaded.
    """
    if n < 1:
        raise ValueError(f"thread count must be >= 1, got {n}")
    for var in _THREAD_VARS:
        os.environ[var] = str(n)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(n)
    except ImportError:  # pragma: no cover - threadpoolctl is a pinned dependency
        pass
    import sys

    import cv2     # OpenCV's pool (erosions, distance transforms) would use every core

    cv2.setNumThreads(n)
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(n)
