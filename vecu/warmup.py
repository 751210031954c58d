"""Kernel loading and warm-up before a timed loop, per pipeline: a brief run of the same pipeline
(the whole plant + ECU run; for a replay a throw-away ECU on the trace's head, not the replay
itself) loads (on a fresh install: compiles) the numba kernels it calls, outside the timed loop."""

from __future__ import annotations

import gc
from collections.abc import Callable

from vecu import kernels
from vecu.clock import Stopwatch

# (kernel backend, pipeline) pairs whose kernels this process has loaded
_loaded: set[tuple[str, str]] = set()


def ensure_kernels(pipeline: str, brief_run: Callable[[], object]) -> float:
    """Under the numba backend, the first call per pipeline in a process runs brief_run (a
    short run of that pipeline, nothing written) and returns the seconds it took; 0.0
    afterwards and under the python backend. Timed loops call it before their clock starts and
    report the seconds apart (kernel_load_s)."""
    key = (kernels.backend(), pipeline)
    if key[0] != "numba" or key in _loaded:
        return 0.0
    _loaded.add(key)  # first: the brief run must not recurse
    watch = Stopwatch()
    brief_run()
    return watch.elapsed()


def warm_up(pipeline: str, brief_run: Callable[[], object]) -> None:
    """Before a wall-clock loop: brief_run (first numpy / cantools calls, the kernels' loading),
    then the set-up objects are frozen out of the garbage collector's way, so that the first
    ticks keep time."""
    _loaded.add((kernels.backend(), pipeline))
    brief_run()
    gc.collect()
    gc.freeze()
