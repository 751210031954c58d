"""The conformance bench: one fault at a time, `vecu ecu` (and `vecu gateway` for a DoIP fault)
committing it on a bus, the tester command run against them with the bus, IDs and DoIP address
in its environment, every frame on the bus captured, and the tester judged by its exit status
and the frames it sent (vecu.conformance.judge). A tester that does not exit within the timeout
is killed and judged "hung"; the bench goes on with the next fault."""

from __future__ import annotations

import json
import os
import sys
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import can

from vecu.bus import open_bus
from vecu.clock import perf_s, sleep
from vecu.conformance.judge import Frames, Ids, Verdict, judge
from vecu.errors import UnavailableError
from vecu.live.children import spawn, stop_group
from vecu.uds.diag_faults.setting import DiagFaultSetting

READY_TIMEOUT_S = 60.0
DOIP_TARGET = 0x0010  # the gateway's default route to the ECU at 0x7E0 / 0x7E8


@dataclass(frozen=True)
class BenchConfig:
    tester: str                           # a shell command
    faults: tuple[DiagFaultSetting, ...]
    interface: str
    channel: str
    timeout_s: float = 30.0
    doip_port: int = 13400
    ids: Ids = Ids(0x7E0, 0x7E8, 0x7DF)

    def environment(self) -> dict[str, str]:
        return {"VECU_CAN_INTERFACE": self.interface, "VECU_CAN_CHANNEL": self.channel,
                "VECU_UDS_REQUEST_ID": f"0x{self.ids.request:X}",
                "VECU_UDS_RESPONSE_ID": f"0x{self.ids.response:X}",
                "VECU_UDS_FUNCTIONAL_ID": f"0x{self.ids.functional:X}",
                "VECU_DOIP_HOST": "127.0.0.1", "VECU_DOIP_PORT": str(self.doip_port),
                "VECU_DOIP_TARGET": f"0x{DOIP_TARGET:04X}"}


class Capture:
    """Every frame on the bus, stamped on arrival (perf_s), on its own thread."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus, self.frames = bus, []  # type: ignore[var-annotated]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is not None:
                self.frames.append((perf_s(), msg))

    def close(self) -> Frames:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()
        return list(self.frames)


def _vecu(*args: str) -> list[str]:
    return [sys.executable, "-m", "vecu", *args]


def _wait_ready(paths: list[Path], procs: list, what: str) -> None:
    t0 = perf_s()
    while not all(p.exists() for p in paths):
        for proc in procs:
            if proc.poll() is not None:
                raise UnavailableError(f"{what} exited ({proc.returncode}) before it was ready")
        if perf_s() - t0 > READY_TIMEOUT_S:
            raise UnavailableError(f"{what} not ready within {READY_TIMEOUT_S:g} s")
        sleep(0.05)


def run_one(cfg: BenchConfig, setting: DiagFaultSetting, work: Path) -> Verdict:
    bus_args = ("--interface", cfg.interface, "--channel", cfg.channel)
    doip = setting.fault.doip
    ready = [work / "ecu.ready"]
    ecu_cmd = _vecu("ecu", *bus_args, "--sync-timeout", "0", "--no-status", "--quiet",
                    "--ready-file", str(ready[0]),
                    *(() if doip else ("--diag-fault", str(setting))))
    err = open(work / "nodes.err", "w")  # noqa: SIM115 (closed below, after the nodes stop)
    procs = [spawn(ecu_cmd, stdout=err, stderr=err)]
    gw_summary = work / "gateway.json"
    if doip:
        ready.append(work / "gateway.ready")
        procs.append(spawn(_vecu("gateway", *bus_args, "--doip-port", str(cfg.doip_port),
                                 "--no-status", "--quiet", "--ready-file", str(ready[1]),
                                 "--summary", str(gw_summary), "--diag-fault", str(setting)),
                           stdout=err, stderr=err))
    capture = None
    try:
        _wait_ready(ready, procs, "vecu ecu" + (" / vecu gateway" if doip else ""))
        capture = Capture(open_bus(cfg.interface, cfg.channel))
        with open(work / "tester.out", "w") as out, open(work / "tester.err", "w") as terr:
            tester = spawn(["sh", "-c", cfg.tester], stdout=out, stderr=terr,
                           env={**os.environ, **cfg.environment()})
            t0 = perf_s()
            code: int | None
            try:
                code = tester.wait(timeout=cfg.timeout_s)
            except Exception:  # noqa: BLE001 - subprocess.TimeoutExpired: hung
                code = None
            seconds = perf_s() - t0
            stop_group(tester)
        frames = capture.close()
        capture = None
    finally:
        if capture is not None:
            capture.close()
        for proc in procs:
            stop_group(proc)
        err.close()
    extra = {}
    if doip and gw_summary.exists():
        extra = json.loads(gw_summary.read_text()).get("diag_fault_evidence", {})
    after = [(t, m) for t, m in frames if t >= t0]
    v = judge(setting.fault, setting.value, code, seconds if code is not None
              else cfg.timeout_s, after, cfg.ids, extra)
    said = [line for name in ("tester.err", "tester.out")  # its last word: stdout's if any
            for line in (work / name).read_text(errors="replace").strip().splitlines()]
    return replace(v, evidence=v.evidence + (f"; tester said: {said[-1][:200]}" if said else ""))


def run_bench(cfg: BenchConfig, progress: Callable[[Verdict], None] | None = None) -> list[Verdict]:
    """Every fault in turn; a node that fails to start is an "error" verdict (its last words
    as evidence), tried once more first, and the bench goes on."""
    verdicts = []
    for setting in cfg.faults:
        for attempt in (1, 2):
            with tempfile.TemporaryDirectory(prefix="vecu-conformance-") as tmp:
                try:
                    v = run_one(cfg, setting, Path(tmp))
                    break
                except UnavailableError as exc:
                    said = (Path(tmp) / "nodes.err").read_text(errors="replace").strip()
                    v = Verdict(setting.fault.name, setting.value, "error", None, 0.0,
                                setting.fault.expect, "", f"{exc} (attempt {attempt}): "
                                f"{said.splitlines()[-1] if said else 'no output'}")
        verdicts.append(v)
        if progress is not None:
            progress(v)
    return verdicts
