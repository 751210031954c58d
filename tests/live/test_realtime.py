"""`--realtime` / `--cpu` (issue 29 item 2): each measure takes effect where the OS permits it,
and a refused one is a note, never an error. Run in child processes: the test process itself
must not become SCHED_FIFO."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

CHILD = ("import json, os; from vecu.live.realtime import apply_realtime; "
         "r = apply_realtime(True, 0); "
         "print(json.dumps({**r.as_dict(), 'policy': os.sched_getscheduler(0), "
         "'affinity': sorted(os.sched_getaffinity(0))}))")


def _child(prefix: list[str]) -> dict:
    res = subprocess.run([*prefix, sys.executable, "-c", CHILD], capture_output=True, text=True,
                         timeout=60, check=False)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduling")
def test_each_measure_takes_effect_or_is_a_note():
    out = _child([])
    assert out["cpu"] == 0 and out["affinity"] == [0]
    assert out["sched_fifo"] == (out["policy"] == os.SCHED_FIFO)
    if not out["sched_fifo"]:
        assert any("SCHED_FIFO refused" in n for n in out["notes"])
    if not out["memory_locked"]:
        assert any("locking memory" in n for n in out["notes"])


@pytest.mark.skipif(shutil.which("unshare") is None or subprocess.run(
    ["unshare", "-r", "true"], capture_output=True, check=False).returncode != 0,
    reason="no user namespace")
def test_refused_without_the_privilege_is_a_one_line_note():
    """In a user namespace the process is root there but lacks CAP_SYS_NICE in the real one."""
    out = _child(["unshare", "-r"])
    assert not out["sched_fifo"] and out["policy"] != os.SCHED_FIFO
    note = next(n for n in out["notes"] if "SCHED_FIFO refused" in n)
    assert "\n" not in note and "normal priority" in note
