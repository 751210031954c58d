"""What the SocketCAN tests share: is there a real kernel with vcan0 here, and live `vecu`
processes and can-utils tools started the way a user starts them, always torn down.

These tests run on a real Linux SocketCAN kernel: natively where the machine has vcan, else
through ../shared/vcan-vm/vcan-run (a Debian kernel in QEMU; `.ci/run` does that on every stop).
Under emulation Python runs ~20x slower, so every wait is long and nothing here asserts timing:
frames received, answers given, files written."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from vecu.live.scenario import stop_process

CHANNEL = "vcan0"
CAN_UTILS = ("candump", "cansend", "canplayer", "cangen", "isotpsend", "isotprecv")
# generous: the emulated guest starts a vecu process in 10-60 s
START_S = 300.0


def kernel_socketcan() -> str | None:
    """None when this machine has a SocketCAN kernel with vcan0 and can-utils; else why not."""
    if not hasattr(socket, "AF_CAN"):
        return "this Python/kernel has no AF_CAN (run through ../shared/vcan-vm/vcan-run)"
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as s:
            s.bind((CHANNEL,))
    except OSError as exc:
        return f"no SocketCAN {CHANNEL}: {exc} (run through ../shared/vcan-vm/vcan-run)"
    missing = [t for t in CAN_UTILS if shutil.which(t) is None]
    if missing:
        return f"can-utils missing: {', '.join(missing)}"
    return None


def kernel_isotp() -> bool:
    """The kernel's CAN_ISOTP protocol (module can-isotp) is there."""
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_DGRAM, socket.CAN_ISOTP):
            return True
    except (OSError, AttributeError):
        return False


REASON = kernel_socketcan()
if REASON is not None and os.environ.get("VECU_REQUIRE_SOCKETCAN") == "1":  # CI, in the guest
    raise RuntimeError(f"VECU_REQUIRE_SOCKETCAN=1, but {REASON}")
needs_kernel = [pytest.mark.socketcan,
                pytest.mark.skipif(REASON is not None, reason=REASON or "")]


def wait_for(cond: Callable[[], bool], timeout_s: float, poll_s: float = 0.1) -> bool:
    end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > end:
            return False
        time.sleep(poll_s)
    return True


# The emulated CPU runs the ECU ~20x slower than the frames arrive, so its receive backlog never
# ends and the flood bound (docs/live.md 'Floods') would shed sensor and background frames these
# tests count one by one: behaviour, not timing, is tested here, so shedding is off (the bound
# itself is tested on the host: tests/ecu/test_flood.py, tests/live/test_flood_live.py).
EMULATED_ECU = ("--set", "ecu.rx.catch_up_ticks=1000000")


class Processes:
    """Child processes of one test: vecu nodes and can-utils tools, each with its stderr in a
    file; stop() sends the signal a user would (SIGTERM to a node: it flushes its log and
    summary), then SIGKILL after a grace period. close() stops whatever still runs."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, argv: list[str], stdout: Path | None = None) -> subprocess.Popen:
        err = open(self.out / f"{name}.err", "w")  # noqa: SIM115 (closed with the process)
        out = open(stdout, "w") if stdout else subprocess.DEVNULL  # noqa: SIM115 (as err)
        proc = subprocess.Popen(argv, stdout=out, stderr=err, cwd=self.out)
        self.procs[name] = proc
        return proc

    def vecu(self, name: str, *args: str) -> subprocess.Popen:
        """`vecu ARGS...`; a `vecu ecu` never sheds frames here (EMULATED_ECU)."""
        extra = EMULATED_ECU if args[:1] == ("ecu",) else ()
        return self.start(name, [sys.executable, "-m", "vecu", *args, *extra])

    def ready(self, name: str, ready_file: Path, timeout_s: float = START_S) -> None:
        proc = self.procs[name]
        wait_for(lambda: ready_file.exists() or proc.poll() is not None, timeout_s, 0.2)
        assert proc.poll() is None and ready_file.exists(), self.stderr(name)

    def stop(self, name: str, sig: int = signal.SIGTERM, grace_s: float = 120.0) -> int:
        return stop_process(self.procs[name], sig, grace_s)

    def stderr(self, name: str) -> str:
        path = self.out / f"{name}.err"
        return path.read_text()[-3000:] if path.exists() else ""

    def close(self) -> None:
        for name in reversed(list(self.procs)):
            self.stop(name, grace_s=30.0)


def summary(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


def tool(*argv: str, stdin: str | None = None, timeout_s: float = 120.0) -> str:
    """Run a can-utils command to its end; its stdout (a failure is the test's)."""
    res = subprocess.run(list(argv), input=stdin, capture_output=True, text=True,
                         timeout=timeout_s, check=False)
    assert res.returncode == 0, (argv, res.stdout, res.stderr)
    return res.stdout


def ecu_drained(channel: str = CHANNEL, timeout_s: float = START_S) -> bytes:
    """Ask the ECU for TesterPresent over the kernel's ISO-TP and wait for the answer. A node
    takes frames from its socket in order, so once it answers, every frame sent before the
    request has been taken (and counted): the way to stop a slow ECU without frames left in
    its socket."""

    return isotp_request(bytes([0x3E, 0x00]), channel, timeout_s)


def isotp_request(payload: bytes, channel: str = CHANNEL, timeout_s: float = START_S) -> bytes:
    """One request on 0x7E0 and its answer on 0x7E8 through the kernel's CAN_ISOTP (can-isotp's
    isotp.socket wrapper)."""
    import isotp

    s = isotp.socket(timeout=timeout_s)
    try:
        s.bind(channel, isotp.Address(isotp.AddressingMode.Normal_11bits, txid=0x7E0,
                                      rxid=0x7E8))
        s.send(payload)
        return bytes(s.recv())
    finally:
        s.close()
