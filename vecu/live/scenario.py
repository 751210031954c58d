"""A live run as separate processes: ECU first, then the plant for at least S seconds,
optionally a `vecu inject` part way (the plant then runs until `after_s` past the command), then
SIGTERM to the plant and to the ECU; optionally a third process on the bus (`--logger`:
python-can's logger). Used by the live tests and the live benchmark. A SIGTERM to this process
stops the nodes the same way, then it exits 143; every child also has a time limit of its own.

`python -m vecu.live.scenario OUT_DIR [options]` writes OUT_DIR/scenario.json (exit codes, the
paths of each process's summary JSON, log and stderr). Run it inside a private network namespace
for udp_multicast (vecu.live.netns.run_in_namespace).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vecu.clock import NS_PER_MS, NS_PER_S, WallClock
from vecu.live.children import (
    EXIT_TERMINATED,
    GRACE_S,
    Terminated,
    sigterm_unwinds,
    spawn,
)
from vecu.live.options import UDP_DEFAULT_GROUP

POLL_NS = 20 * NS_PER_MS


def _wait_for(cond: Callable[[], bool], timeout_s: float) -> bool:
    clock = WallClock(spin_ns=0)
    clock.start()
    t = 0
    while not cond():
        t += POLL_NS
        if t > timeout_s * NS_PER_S:
            return False
        clock.wait_until(t)
    return True


def _spawn(argv: list[str], err_path: Path) -> subprocess.Popen:
    """A node process that dies with this one, in this process group (vecu.live.children)."""
    with open(err_path, "w") as err:
        return spawn(argv, new_group=False, stdout=subprocess.DEVNULL, stderr=err)


def stop_process(proc: subprocess.Popen, sig: int, grace_s: float = GRACE_S) -> int:
    """Send sig (a node flushes its log and summary on SIGTERM, the logger on SIGINT), wait up to
    grace_s, then SIGKILL; always reaped. Its exit code."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=grace_s)
    if proc.poll() is None:
        proc.kill()
    return proc.wait()


def stop_all(procs: list[subprocess.Popen], sig: int = signal.SIGTERM,
             grace_s: float = GRACE_S) -> list[int]:
    """Signal every process first (so they stop side by side), then reap each as stop_process
    does; their exit codes."""
    for proc in procs:
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(sig)
    return [stop_process(proc, sig, grace_s) for proc in procs]


def run_scenario(out: Path, plant_seconds: float, inject_at: float | None, inject_kind: str,
                 extra_load: float, interface: str, channel: str, ecu_args: list[str],
                 plant_args: list[str], log: bool, after_s: float = 1.5,
                 start_timeout_s: float = 90.0, logger: bool = False,
                 cpu_load: int = 0) -> dict[str, Any]:
    """The live run; logger: a third process on the bus (`python -m can.logger` writing
    OUT/logger.log), started before the ECU. Every child has a time limit of its own (--duration,
    well past the planned stop) and dies with this process; on Terminated (a SIGTERM under
    sigterm_unwinds) the nodes are stopped as on their own SIGTERM and scenario.json records it.
    cpu_load: that many busy-looping processes while the plant runs (a loaded host; each ends
    on its own after the plant's time limit at the latest)."""
    out.mkdir(parents=True, exist_ok=True)
    vecu = [sys.executable, "-m", "vecu"]
    bus = ["--interface", interface, "--channel", channel, "--no-status", "--quiet"]
    res: dict[str, Any] = {"plant_seconds": plant_seconds, "interface": interface,
                           "channel": channel, "ecu_summary": str(out / "ecu.json"),
                           "plant_summary": str(out / "plant.json"),
                           "ecu_log": str(out / "ecu.log") if log else None,
                           "logger_log": str(out / "logger.log") if logger else None,
                           "stopped_by": "plan"}
    # backstops: the plant's planned run plus the inject wait, the ECU's on top of the plant's
    plant_limit_s = plant_seconds + (inject_at or 0.0) + after_s + start_timeout_s + 60.0
    ecu_limit_s = plant_limit_s + start_timeout_s + 60.0
    procs: dict[str, subprocess.Popen] = {}
    try:
        if logger:
            procs["logger"] = _spawn([sys.executable, "-m", "can.logger", "-i", interface,
                                      "-c", channel, "-f", str(out / "logger.log")],
                                     out / "logger.err")
        ecu_cmd = [*vecu, "ecu", *bus, "--summary", str(out / "ecu.json"),
                   "--ready-file", str(out / "ecu.ready"), "--sync-timeout", str(start_timeout_s),
                   "--duration", f"{ecu_limit_s:g}",
                   *(["--log", str(out / "ecu.log")] if log else []), *ecu_args]
        ecu = procs["ecu"] = _spawn(ecu_cmd, out / "ecu.err")
        if not _wait_for(lambda: (out / "ecu.ready").exists() or ecu.poll() is not None,
                         start_timeout_s):
            res["error"] = "ECU did not get ready"
        plant_cmd = [*vecu, "plant", *bus, "--summary", str(out / "plant.json"),
                     "--ready-file", str(out / "plant.ready"), "--duration", f"{plant_limit_s:g}",
                     *(["--extra-load", str(extra_load)] if extra_load else []), *plant_args]
        plant = procs["plant"] = _spawn(plant_cmd, out / "plant.err")
        clock = WallClock(spin_ns=0)
        clock.start()
        _wait_for(lambda: (out / "plant.ready").exists() or plant.poll() is not None,
                  start_timeout_s)
        end_ns = clock.now_ns() + int(plant_seconds * NS_PER_S)
        for i in range(cpu_load):
            procs[f"load{i}"] = _spawn([sys.executable, "-c", BUSY.format(s=plant_limit_s)],
                                       out / f"load{i}.err")
        if inject_at is not None:  # the plant runs on until the command is sent, and after_s more
            inject = procs["inject"] = _spawn(
                [*vecu, "inject", "--interface", interface, "--channel", channel, "--target", "tps",
                 "--kind", inject_kind, "--at", str(inject_at), "--quiet"], out / "inject.err")
            inject.wait(timeout=start_timeout_s + inject_at)
            end_ns = max(end_ns, clock.now_ns() + int(after_s * NS_PER_S))
        clock.wait_until(end_ns)
        stop_process(plant, signal.SIGTERM, 60.0)
        _wait_for(lambda: False, 0.5)  # let the ECU drain what is still queued
        stop_process(ecu, signal.SIGTERM, 60.0)
    except Terminated:
        res["stopped_by"] = "SIGTERM"
        raise
    finally:  # plant before the ECU (it drains), the logger last (it sees everything)
        for name in ("inject", *(f"load{i}" for i in range(cpu_load)), "plant", "ecu",
                     "logger"):
            if name in procs:
                stop_process(procs[name], signal.SIGINT if name == "logger" else signal.SIGTERM)
        res["returncodes"] = {name: p.returncode for name, p in procs.items()}
        res["stderr"] = {name: (out / f"{name}.err").read_text()[-2000:] for name in procs}
        if logger and (out / "logger.log").exists():
            with open(out / "logger.log", "rb") as f:
                res["logger_frames"] = sum(1 for _ in f)
        (out / "scenario.json").write_text(json.dumps(res, indent=2) + "\n")
    return res


BUSY = "import time\nend = time.monotonic() + {s}\nwhile time.monotonic() < end:\n    pass\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m vecu.live.scenario")
    p.add_argument("out", type=Path)
    p.add_argument("--plant-seconds", type=float, default=4.0)
    p.add_argument("--inject-at", type=float)
    p.add_argument("--inject-kind", default="dead")
    p.add_argument("--extra-load", type=float, default=0.0)
    p.add_argument("--interface", default="udp_multicast")
    p.add_argument("--channel", default=UDP_DEFAULT_GROUP)
    p.add_argument("--no-log", action="store_true")
    p.add_argument("--logger", action="store_true",
                   help="a third process on the bus: python -m can.logger -> OUT/logger.log")
    p.add_argument("--ecu-arg", action="append", default=[], help="extra `vecu ecu` argument")
    p.add_argument("--plant-arg", action="append", default=[], help="extra `vecu plant` argument")
    p.add_argument("--cpu-load", type=int, default=0, help="busy processes while the plant runs")
    a = p.parse_args(argv)
    try:
        with sigterm_unwinds():
            res = run_scenario(a.out, a.plant_seconds, a.inject_at, a.inject_kind, a.extra_load,
                               a.interface, a.channel, a.ecu_arg, a.plant_arg, not a.no_log,
                               logger=a.logger, cpu_load=a.cpu_load)
    except Terminated:
        return EXIT_TERMINATED
    return 0 if all(rc == 0 for name, rc in res["returncodes"].items()
                    if name != "logger" and not name.startswith("load")) else 1


if __name__ == "__main__":
    sys.exit(main())
