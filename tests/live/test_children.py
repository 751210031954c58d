"""Children die with their parent (issue 14 item 11): a SIGTERM to a vecu command that started
processes stops every one of them (grandchildren included), the parent exits 143 after that,
and nothing a test starts here outlives it (each test kills what it found, whatever happens).

Processes are found and checked in /proc: descendants of the command's pid, alive unless gone
or a zombie, with their start time so a reused pid is not mistaken for a survivor."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from vecu.live.children import spawn
from vecu.live.netns import namespace_prefix, wrap
from vecu.live.scenario import _wait_for

TERMINATED = 128 + signal.SIGTERM
no_netns = pytest.mark.skipif(namespace_prefix()[0] is None,
                              reason=namespace_prefix()[1] or "n/a")


def _stat(pid: int) -> tuple[int, str, int] | None:
    """(ppid, state, start time) of a process, None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), fields[0], int(fields[19])


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def descendants(root: int) -> dict[int, tuple[int, str]]:
    """Every living process below root: pid -> (start time, command line)."""
    parents: dict[int, int] = {}
    starts: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (st := _stat(int(entry))) is not None and st[1] != "Z":
            parents[int(entry)], starts[int(entry)] = st[0], st[2]
    found: dict[int, tuple[int, str]] = {}
    frontier = [root]
    while frontier:
        parent = frontier.pop()
        for pid, ppid in parents.items():
            if ppid == parent and pid not in found:
                found[pid] = (starts[pid], _cmdline(pid))
                frontier.append(pid)
    return found


def alive(pid: int, start: int) -> bool:
    st = _stat(pid)
    return st is not None and st[1] != "Z" and st[2] == start


@contextlib.contextmanager
def watched(argv: list[str], **kwargs) -> Iterator[tuple[subprocess.Popen, dict]]:
    """Start argv (its own process group); on the way out SIGKILL it and every descendant ever
    seen (yielded dict, filled by the test), so a failing test leaves nothing running."""
    proc = spawn(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **kwargs)
    seen: dict[int, tuple[int, str]] = {}
    try:
        yield proc, seen
    finally:
        seen.update(descendants(proc.pid))
        for pid, (start, _) in seen.items():
            if alive(pid, start):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(OSError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.kill()
        proc.communicate()


def wait_for_children(proc: subprocess.Popen, seen: dict, ready: Callable[[dict], bool],
                      timeout_s: float) -> None:
    def check() -> bool:
        seen.update(descendants(proc.pid))
        return ready(seen) or proc.poll() is not None
    assert _wait_for(check, timeout_s), f"children not seen in {timeout_s} s: {seen}"
    assert proc.poll() is None, proc.stderr.read()[-2000:]


def assert_all_gone(seen: dict, timeout_s: float = 10.0) -> None:
    def gone() -> bool:
        return not any(alive(pid, start) for pid, (start, _) in seen.items())
    survivors = {}
    if not _wait_for(gone, timeout_s):
        survivors = {pid: cmd for pid, (start, cmd) in seen.items() if alive(pid, start)}
    assert not survivors, survivors


def test_sigterm_to_a_bounded_run_stops_the_whole_group_and_exits_143():
    """run_bounded's child starts a grandchild that has no parent-death signal of its own: the
    SIGTERM handler of the parent must stop the group, not only die."""
    code = ("import sys\nfrom vecu.live import children\ntry:\n"
            "    children.run_bounded(['sh', '-c', 'sleep 300 & sleep 300'], timeout=600)\n"
            "except BaseException as exc:\n"
            "    sys.exit(143 if type(exc).__name__ == 'Terminated' else 3)\n")
    with watched([sys.executable, "-c", code]) as (proc, seen):
        wait_for_children(proc, seen, lambda s: sum("sleep 300" in c for _, c in s.values()) >= 2,
                          60.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == TERMINATED, proc.stderr.read()[-2000:]
        assert_all_gone(seen)


def _long_scenarios(tmp: Path) -> list[str]:
    paths = []
    for name in ("day_a", "day_b"):
        p = tmp / f"{name}.toml"
        p.write_text(f'name = "{name}"\nduration_s = 86400.0\nseed = 1\n')
        paths.append(str(p))
    return paths


def test_sigterm_to_scenario_run_with_jobs_stops_its_workers(tmp_path):
    """Worker processes of `vecu scenario run --jobs 2` ran on for the length of their (here:
    day-long) scenarios after the command was stopped."""
    argv = [sys.executable, "-m", "vecu", "scenario", "run", "--jobs", "2",
            *_long_scenarios(tmp_path)]
    with watched(argv, env={**os.environ, "VECU_KERNELS": "python"}) as (proc, seen):
        wait_for_children(proc, seen, lambda s: len(s) >= 2, 120.0)
        _wait_for(lambda: False, 1.0)  # the workers are inside their runs
        seen.update(descendants(proc.pid))
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        assert_all_gone(seen)


@no_netns
def test_sigterm_to_vecu_bench_live_stops_plant_and_ecu_and_exits_143():
    argv = [sys.executable, "-m", "vecu", "bench", "--only", "live", "--quick",
            "--live-seconds", "2", "--memory-minutes", "0.05"]

    def both(s: dict) -> bool:
        cmds = [c for _, c in s.values()]
        return any("-m vecu ecu" in c for c in cmds) and any("-m vecu plant" in c for c in cmds)

    with watched(argv) as (proc, seen):
        wait_for_children(proc, seen, both, 180.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == TERMINATED, proc.stderr.read()[-2000:]
        assert_all_gone(seen)


@no_netns
def test_sigterm_to_a_live_scenario_stops_plant_and_ecu_cleanly(tmp_path):
    """The live scenario passes the SIGTERM on: plant and ECU stop as on their own SIGTERM
    (summaries written), then it exits 143; nothing is left."""
    argv = wrap([sys.executable, "-m", "vecu.live.scenario", str(tmp_path),
                 "--plant-seconds", "60", "--no-log"], namespace_prefix()[0])
    with watched(argv) as (proc, seen):
        wait_for_children(proc, seen, lambda s: (tmp_path / "plant.ready").exists(), 180.0)
        seen.update(descendants(proc.pid))
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == TERMINATED, proc.stderr.read()[-2000:]
        assert_all_gone(seen)
    for role in ("ecu", "plant"):
        summary = json.loads((tmp_path / f"{role}.json").read_text())
        assert summary["stopped_by"] == "SIGTERM"
    res = json.loads((tmp_path / "scenario.json").read_text())
    assert res["stopped_by"] == "SIGTERM" and res["returncodes"] == {"ecu": 0, "plant": 0}
