"""Child processes that cannot outlive their parent: a time limit, their own process group
(stopped whole on a timeout, a SIGTERM or any error in the parent) and, on Linux, a parent-death
signal (prctl PR_SET_PDEATHSIG), so that a killed bench or test leaves no plant or ECU running.

A SIGTERM to a parent that waits in run_bounded (or runs inside sigterm_unwinds) raises
Terminated there: `finally` blocks stop the children (SIGTERM to their group, SIGKILL after a
grace period), then the command exits 143 (128 + SIGTERM)."""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

PR_SET_PDEATHSIG = 1
EXIT_TERMINATED = 128 + signal.SIGTERM
GRACE_S = 5.0  # SIGTERM -> SIGKILL: time for a live node to flush its log and summary


class Terminated(BaseException):
    """SIGTERM arrived (inside sigterm_unwinds): unwinds the stack so children are stopped."""


@contextlib.contextmanager
def sigterm_unwinds() -> Iterator[None]:
    """Within the block a SIGTERM raises Terminated (once; a second one is ignored while the
    first unwinds). A no-op off the main thread or when SIGTERM already has a handler (a live
    process's stop flag)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated(signal.Signals(signum).name)

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


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


def dies_with(parent_pid: int) -> Callable[[], None]:
    """preexec_fn: die_with_parent, and exit at once if the parent (parent_pid) died before the
    signal was armed (prctl only covers a death after it)."""

    def preexec() -> None:
        die_with_parent()
        if os.getppid() != parent_pid:
            os._exit(EXIT_TERMINATED)

    return preexec


def spawn(argv: list[str], new_group: bool = True, **kwargs: Any) -> subprocess.Popen:
    """Popen that dies with this process; by default in its own process group (stop_group /
    kill_group stop it whole), else in this one (a SIGTERM to the group reaches it too)."""
    return subprocess.Popen(argv, start_new_session=new_group,
                            preexec_fn=dies_with(os.getpid()), **kwargs)  # noqa: PLW1509 (prctl only: fork-safe)


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the child's process group (the child and everything it started) and reap it."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(ProcessLookupError):
        proc.kill()
    proc.wait()


def stop_group(proc: subprocess.Popen, grace_s: float = GRACE_S) -> None:
    """SIGTERM the child's process group (live nodes flush their logs and summaries), SIGKILL
    whatever is left after grace_s (or at once if the child is gone), and reap the child."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=grace_s)
    kill_group(proc)


def run_bounded(argv: list[str], timeout: float, **kwargs: Any) -> subprocess.CompletedProcess:
    """subprocess.run(argv, capture_output=True, text=True) in its own process group, stopped
    whole (grandchildren included) on the timeout (TimeoutExpired is raised), a SIGTERM to this
    process (Terminated is raised) or any error."""
    with sigterm_unwinds():
        proc = spawn(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)
        try:
            out, err = proc.communicate(timeout=timeout)
        except BaseException:
            stop_group(proc)
            proc.communicate()
            raise
        kill_group(proc)  # whatever the child left behind in its group
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)
