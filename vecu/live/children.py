"""Child processes that cannot outlive their parent: a time limit, their own process group
(killed whole on a timeout or any error in the parent) and, on Linux, a parent-death signal
(prctl PR_SET_PDEATHSIG), so that a killed bench or test leaves no plant or ECU running."""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
from typing import Any

PR_SET_PDEATHSIG = 1


def _resolve_prctl() -> Any:
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


_PRCTL = _resolve_prctl()  # looked up here, not in the forked child


def die_with_parent() -> None:
    """preexec_fn: SIGKILL this child when the thread that started it exits (Linux; a no-op
    elsewhere). Kept across exec, so it holds for the program the child runs. It only calls the
    prctl resolved at import, which keeps it safe enough as a preexec_fn."""
    if _PRCTL is not None:
        _PRCTL(PR_SET_PDEATHSIG, signal.SIGKILL)


def spawn(argv: list[str], **kwargs: Any) -> subprocess.Popen:
    """Popen that dies with this process (its own process group: kill_group stops it whole)."""
    return subprocess.Popen(argv, start_new_session=True,
                            preexec_fn=die_with_parent, **kwargs)  # noqa: PLW1509 (see there)


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the child's process group (the child and everything it started) and reap it."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(ProcessLookupError):
        proc.kill()
    proc.wait()


def run_bounded(argv: list[str], timeout: float, **kwargs: Any) -> subprocess.CompletedProcess:
    """subprocess.run(argv, capture_output=True, text=True) in its own process group, killed
    whole (grandchildren included) on the timeout (TimeoutExpired is raised) or any error."""
    proc = spawn(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        kill_group(proc)
        proc.communicate()
        raise
    kill_group(proc)  # whatever the child left behind in its group
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)
