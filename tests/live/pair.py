"""`vecu ecu` and `vecu plant` started side by side for a live test script (inside its private
network namespace): the ECU first (it syncs to the plant's first frames), each awaited by its
ready file, stderr to OUT/ecu.err and OUT/plant.err."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def _await(path: Path, timeout_s: float = 60.0) -> None:
    end = time.monotonic() + timeout_s
    while not path.exists() and time.monotonic() < end:
        time.sleep(0.1)


def start_ecu_and_plant(out: Path, bus: list[str], ecu_args: tuple[str, ...] = (),
                        ecu_s: float = 120, plant_s: float = 90,
                        plant_args: tuple[str, ...] = (),
                        more_ecus: tuple[tuple[str, ...], ...] = ()) -> list[subprocess.Popen]:
    """[ecu, more ECUs..., plant], all ready; the ECU's summary goes to OUT/ecu.json, the k-th
    more ECU's (its own arguments, e.g. --instance 1) to OUT/ecu<k>.json. The caller stops them
    (vecu.live.scenario.stop_all)."""
    vecu = [sys.executable, "-m", "vecu"]
    procs = []
    for name, args in (("ecu", ecu_args),
                       *((f"ecu{k}", more) for k, more in enumerate(more_ecus, 1))):
        procs.append(subprocess.Popen(
            [*vecu, "ecu", *bus, "--ready-file", str(out / f"{name}.ready"), "--sync-timeout",
             "20", "--duration", f"{ecu_s:g}", "--summary", str(out / f"{name}.json"), "--quiet",
             *args], stderr=open(out / f"{name}.err", "w")))  # noqa: SIM115 (the child owns it)
        _await(out / f"{name}.ready")
    procs.append(subprocess.Popen(
        [*vecu, "plant", *bus, "--duration", f"{plant_s:g}", "--quiet", "--ready-file",
         str(out / "plant.ready"), *plant_args], stderr=open(out / "plant.err", "w")))  # noqa: SIM115 (the child owns it)
    _await(out / "plant.ready")
    return procs


def ecu_summary(out: Path) -> tuple[dict, float]:
    """The ECU's summary (OUT/ecu.json, {} if none) and the share of its ticks it ran."""
    path = out / "ecu.json"
    summary = json.loads(path.read_text()) if path.exists() else {}
    ticks = summary.get("ticks", {}).get("ecu", {})
    return summary, ticks.get("runs", 0) / max(ticks.get("releases", 1), 1)


def await_ecu(client: Any, attempts: int = 60) -> None:
    """TesterPresent until the ECU answers (a live ECU ticks once it has synced to the plant's
    first frames); a udsoncan Client."""
    from udsoncan.exceptions import TimeoutException

    for _ in range(attempts):
        try:
            client.tester_present()
            return
        except TimeoutException:
            continue


def run_script(script: Path, out: Path, timeout: float) -> dict:
    """Run a live test script (python SCRIPT OUT) in a private network namespace and return
    the JSON line it printed last; a failure shows its output and its children's OUT/*.err."""
    from vecu.live.netns import run_in_namespace

    res = run_in_namespace([sys.executable, str(script), str(out)], timeout=timeout)
    assert res.returncode == 0, res.stderr + res.stdout + "".join(
        p.read_text() for p in out.glob("*.err"))
    return json.loads(res.stdout.strip().splitlines()[-1])
