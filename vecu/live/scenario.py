"""A live run as separate processes: ECU first, then the plant for at least S seconds,
optionally a `vecu inject` part way (the plant then runs until `after_s` past the command), then
SIGTERM to the plant and to the ECU. Used by the live tests and the live benchmark.

`python -m vecu.live.scenario OUT_DIR [options]` writes OUT_DIR/scenario.json (exit codes, the
paths of each process's summary JSON, log and stderr). Run it inside a private network namespace
for udp_multicast (vecu.live.netns.run_in_namespace).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vecu.clock import NS_PER_MS, NS_PER_S, WallClock
from vecu.live.children import die_with_parent
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
    """A node process that dies with this one (vecu.live.children)."""
    with open(err_path, "w") as err:
        return subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err,
                                preexec_fn=die_with_parent)  # noqa: PLW1509


def run_scenario(out: Path, plant_seconds: float, inject_at: float | None, inject_kind: str,
                 extra_load: float, interface: str, channel: str, ecu_args: list[str],
                 plant_args: list[str], log: bool, after_s: float = 1.5,
                 start_timeout_s: float = 90.0) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    vecu = [sys.executable, "-m", "vecu"]
    bus = ["--interface", interface, "--channel", channel, "--no-status", "--quiet"]
    res: dict[str, Any] = {"plant_seconds": plant_seconds, "interface": interface,
                           "channel": channel, "ecu_summary": str(out / "ecu.json"),
                           "plant_summary": str(out / "plant.json"),
                           "ecu_log": str(out / "ecu.log") if log else None}
    ecu_cmd = [*vecu, "ecu", *bus, "--summary", str(out / "ecu.json"),
               "--ready-file", str(out / "ecu.ready"), "--sync-timeout", str(start_timeout_s),
               *(["--log", str(out / "ecu.log")] if log else []), *ecu_args]
    ecu = _spawn(ecu_cmd, out / "ecu.err")
    procs = {"ecu": ecu}
    try:
        if not _wait_for(lambda: (out / "ecu.ready").exists() or ecu.poll() is not None,
                         start_timeout_s):
            res["error"] = "ECU did not get ready"
        plant_cmd = [*vecu, "plant", *bus, "--summary", str(out / "plant.json"),
                     "--ready-file", str(out / "plant.ready"),
                     "--steering-horizon", str(max(plant_seconds + start_timeout_s, 20.0)),
                     *(["--extra-load", str(extra_load)] if extra_load else []), *plant_args]
        plant = procs["plant"] = _spawn(plant_cmd, out / "plant.err")
        clock = WallClock(spin_ns=0)
        clock.start()
        _wait_for(lambda: (out / "plant.ready").exists() or plant.poll() is not None,
                  start_timeout_s)
        end_ns = clock.now_ns() + int(plant_seconds * NS_PER_S)
        if inject_at is not None:  # the plant runs on until the command is sent, and after_s more
            inject = procs["inject"] = _spawn(
                [*vecu, "inject", "--interface", interface, "--channel", channel, "--target", "tps",
                 "--kind", inject_kind, "--at", str(inject_at), "--quiet"], out / "inject.err")
            inject.wait(timeout=start_timeout_s + inject_at)
            end_ns = max(end_ns, clock.now_ns() + int(after_s * NS_PER_S))
        clock.wait_until(end_ns)
        plant.send_signal(signal.SIGTERM)
        plant.wait(timeout=60)
        _wait_for(lambda: False, 0.5)  # let the ECU drain what is still queued
        ecu.send_signal(signal.SIGTERM)
        ecu.wait(timeout=60)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    res["returncodes"] = {name: p.returncode for name, p in procs.items()}
    res["stderr"] = {name: (out / f"{name}.err").read_text()[-2000:] for name in procs}
    (out / "scenario.json").write_text(json.dumps(res, indent=2) + "\n")
    return res


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
    p.add_argument("--ecu-arg", action="append", default=[], help="extra `vecu ecu` argument")
    p.add_argument("--plant-arg", action="append", default=[], help="extra `vecu plant` argument")
    a = p.parse_args(argv)
    res = run_scenario(a.out, a.plant_seconds, a.inject_at, a.inject_kind, a.extra_load,
                       a.interface, a.channel, a.ecu_arg, a.plant_arg, not a.no_log)
    return 0 if all(rc == 0 for rc in res["returncodes"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
