"""Real-time scheduling for a live node where the OS permits it (`--realtime`, `--cpu N`):
SCHED_FIFO, CPU affinity and locked memory, so a busy machine's other processes delay the 1 ms
tick less. Each measure that is refused (no CAP_SYS_NICE / RLIMIT_RTPRIO, no CAP_IPC_LOCK /
RLIMIT_MEMLOCK, a CPU not there) leaves the node running as before, with a one-line note."""

from __future__ import annotations

import ctypes
import os
import sys
from dataclasses import dataclass, field

RT_PRIORITY = 50  # SCHED_FIFO 1..99: above ordinary tasks, below the kernel's own threads
MCL_CURRENT, MCL_FUTURE = 1, 2


@dataclass
class RealtimeResult:
    sched_fifo: bool = False
    cpu: int | None = None
    memory_locked: bool = False
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"sched_fifo": self.sched_fifo, "cpu": self.cpu,
                "memory_locked": self.memory_locked, "notes": list(self.notes)}


def apply_realtime(enabled: bool, cpu: int | None, priority: int = RT_PRIORITY) -> RealtimeResult:
    """Ask for SCHED_FIFO at `priority` and locked memory (when enabled) and pin to `cpu`
    (when given); what the OS refuses is a note, never an error."""
    res = RealtimeResult()
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
            res.cpu = cpu
        except (OSError, AttributeError, ValueError) as exc:
            res.notes.append(f"CPU affinity {cpu} refused ({_reason(exc)}): any CPU")
    if not enabled:
        return res
    if not sys.platform.startswith("linux"):
        res.notes.append("real-time scheduling needs Linux: normal priority")
        return res
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        res.sched_fifo = True
    except (OSError, AttributeError) as exc:
        res.notes.append(f"SCHED_FIFO refused ({_reason(exc)}; needs CAP_SYS_NICE or an "
                         "rtprio limit): normal priority")
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
            res.memory_locked = True
        else:
            err = ctypes.get_errno()
            res.notes.append(f"locking memory refused ({os.strerror(err)}; needs CAP_IPC_LOCK "
                             "or a memlock limit): pages may be swapped")
    except (OSError, AttributeError) as exc:
        res.notes.append(f"locking memory unavailable ({_reason(exc)})")
    return res


def _reason(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
