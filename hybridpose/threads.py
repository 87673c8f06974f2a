"""How many CPU threads the per-frame work runs on, set in one place for every library it calls:
torch's intra-op pool (and ONNX Runtime's sessions, which follow it), OpenCV and numba.

One thread is the default, for ``track``, the Python API and ``bench`` alike: on an idle 2-core
machine a frame costs about the same on one thread or two, but beside other busy work (a robot's
other software, a training job) a library that spreads over every core waits for the cores it
shares: the hybrid's frame took 1.3× (a spinning loop on each core) to 2.4× (a training job and its
renderers) as long as on one thread. Set another count with ``HYBRIDPOSE_THREADS=N`` in the
environment, ``hybridpose track --threads N`` or ``HybridEstimator(..., threads=N)``.
"""
from __future__ import annotations

import numbers
import os
import sys

ENV_VAR = "HYBRIDPOSE_THREADS"
DEFAULT_THREADS = 1  # intra-op threads a process unless HYBRIDPOSE_THREADS says otherwise


def default_threads() -> int:
    """``HYBRIDPOSE_THREADS`` where set (a whole number ≥ 1; ValueError naming it otherwise), else
    :data:`DEFAULT_THREADS`."""
    text = os.environ.get(ENV_VAR, "").strip()
    if not text:
        return DEFAULT_THREADS
    try:
        threads = int(text)
    except ValueError:
        threads = 0
    if threads < 1:
        raise ValueError(f"{ENV_VAR}: expected a whole number of threads ≥ 1, got {text!r}")
    return threads


def set_threads(threads: int | None = None) -> int:
    """Run per-frame work on ``threads`` CPU threads (None: :func:`default_threads`); returns the count.

    Sets torch's intra-op threads (where torch is imported; else ``OMP_NUM_THREADS``, which torch reads
    when it is), OpenCV's and numba's. The setting is the process's: the last call wins."""
    threads = default_threads() if threads is None else threads
    if isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1:
        raise ValueError(f"threads: expected a whole number ≥ 1, got {threads!r}")
    import cv2

    threads = int(threads)
    cv2.setNumThreads(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)
    else:
        os.environ["OMP_NUM_THREADS"] = str(threads)
    if "numba" in sys.modules:
        numba = sys.modules["numba"]
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    return threads
