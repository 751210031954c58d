"""A steppable simulated run (plant + ECU with its UDS server on one virtual channel) and a
udsoncan tester on its own thread: the test drives the simulated clock while the tester talks."""

from __future__ import annotations

import itertools
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import isotp
import udsoncan
from udsoncan.client import Client
from udsoncan.connections import PythonIsoTpConnection

from vecu.assembly import (
    TICK_NS,
    build_functions,
    build_plant,
    schedule_ecu,
    schedule_plant,
)
from vecu.bus import open_bus
from vecu.clock import NS_PER_S, SimClock
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.faults import FaultInjector, FaultTarget, parse_kind
from vecu.scheduler import Scheduler
from vecu.uds.security import key_from_seed
from vecu.uds.server import UdsServer, attach_uds

_channels = itertools.count()


class Codec(udsoncan.DidCodec):
    """A DID as docs/uds.md describes it: struct format and scale (None: not available)."""

    def __init__(self, fmt: str, scale: float = 1.0) -> None:
        self.fmt, self.scale = ">" + fmt, scale

    def encode(self, value: float) -> bytes:  # type: ignore[override]  # narrower than udsoncan's DidCodec method
        return struct.pack(self.fmt, round(value / self.scale))

    def decode(self, data: bytes) -> Any:  # type: ignore[override]  # narrower than udsoncan's DidCodec method
        if self.fmt.endswith("s"):
            return data.decode("ascii")
        return struct.unpack(self.fmt, data)[0] * self.scale

    def __len__(self) -> int:
        return struct.calcsize(self.fmt)


# what a tester writes from docs/uds.md
DIDS = {0xF190: Codec("17s"), 0xF18C: Codec("10s"), 0xF195: Codec("15s"), 0xF186: Codec("B"),
        0x0001: Codec("I"), 0x0002: Codec("I"), 0x0003: Codec("H"), 0x0004: Codec("H"),
        0x0100: Codec("H", 0.01), 0x0101: Codec("H", 0.01),
        0x0102: Codec("H", 0.01), 0x0103: Codec("B"), 0x0104: Codec("H", 0.0001),
        0x0105: Codec("B"), 0x0110: Codec("H", 0.01), 0x0200: Codec("H", 0.01),
        0x0300: Codec("H", 0.01), 0x0400: Codec("h", 0.05), 0x0402: Codec("h", 0.01),
        0x0403: Codec("h", 0.05), 0x010F: Codec("B"), 0x020F: Codec("B"), 0x030F: Codec("B"),
        0x040F: Codec("B"), 0x0305: Codec("H", 0.01), 0x0405: Codec("H", 0.01),
        0x0204: Codec("H", 0.001)}
CLIENT_CONFIG = {**udsoncan.configs.default_client_config, "data_identifiers": DIDS,
                 "input_output": {0x0104: Codec("H", 0.0001), 0x0302: Codec("H", 0.01),
                                  0x0403: Codec("h", 0.05)},
                 "security_algo": lambda level, seed, params: key_from_seed(seed),
                 "extended_data_size": 1, "request_timeout": 5.0, "p2_timeout": 2.0,
                 "p2_star_timeout": 5.0, "use_server_timing": False}


def client_config(**over: Any) -> dict[str, Any]:
    return {**CLIENT_CONFIG, **over}


class SimRun:
    """Plant and ECU on a fresh virtual channel; step() advances the simulated clock."""

    def __init__(self, config: RunConfig | None = None) -> None:
        self.config = config or RunConfig(duration_s=600.0, kill_tps_at_s=None)
        self.channel = f"uds-test-{next(_channels)}"
        self.codec = DbcCodec()
        self.buses = [open_bus("virtual", self.channel) for _ in range(2)]
        self.injector = FaultInjector(__import__("numpy").random.default_rng(0))
        self.plant = build_plant(self.config, self.codec, self.buses[0], self.injector)
        self.fns = build_functions(self.config, self.codec)
        self.ecu = EcuNode(self.buses[1], self.codec, self.fns.enabled())
        server = attach_uds(self.ecu, self.config.params.ecu.uds, self.config.seed)
        assert server is not None
        self.uds: UdsServer = server
        self.sched = Scheduler(SimClock())
        schedule_plant(self.sched, self.plant)
        schedule_ecu(self.sched, self.ecu)
        self.t_ns = 0

    def kill(self, target: FaultTarget, kind: str = "dead", value: float | None = None) -> None:
        self.injector.inject(self.t_ns, target, parse_kind(kind), value, source="test")

    def step(self, ticks: int = 1) -> None:
        self.t_ns += ticks * TICK_NS
        self.sched.run_until(self.t_ns)

    def run_to(self, t_s: float) -> None:
        self.step(max(0, round(t_s * NS_PER_S) - self.t_ns) // TICK_NS)

    def bus(self) -> Any:
        bus = open_bus("virtual", self.channel)
        self.buses.append(bus)
        return bus

    def serve(self, work: Callable[[Client], Any], config: dict[str, Any] | None = None,
              max_sim_s: float = 120.0, pace_s: float = 0.0002) -> Any:
        """Run `work(client)` (a udsoncan Client over can-isotp on this channel) on a thread
        while the simulated clock steps 1 ms at a time; its result (or its exception)."""
        bus = self.bus()
        stack = isotp.CanStack(bus, address=isotp.Address(
            isotp.AddressingMode.Normal_11bits, txid=0x7E0, rxid=0x7E8),
            params={"tx_padding": 0xCC, "blocking_send": False})
        return drive_tester(stack, work, self.step, config, round(max_sim_s * NS_PER_S) // TICK_NS,
                            pace_s)

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()


def drive_tester(stack: isotp.CanStack, work: Callable[[Client], Any], step: Callable[[], None],
                 config: dict[str, Any] | None = None, max_ticks: int = 120_000,
                 pace_s: float = 0.0002) -> Any:
    """Run `work(client)` (a udsoncan Client over `stack`) on a thread while step() advances a
    simulated clock 1 ms at a time (at most max_ticks); its result (or its exception)."""
    def body() -> Any:
        with Client(PythonIsoTpConnection(stack), config=config or CLIENT_CONFIG) as c:
            return work(c)

    return run_stepped(body, step, max_ticks, pace_s, who="tester")


def run_stepped(body: Callable[[], Any], step: Callable[[], None], max_ticks: int,
                pace_s: float, settle_s: float = 0.0, who: str = "tester") -> Any:
    """body() on a thread (after settle_s, the clock still) while step() advances the simulated
    clock 1 ms at a time, at most max_ticks; its result, or its exception raised here."""
    out: dict[str, Any] = {}

    def run() -> None:
        try:
            out["result"] = body()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            out["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    time.sleep(settle_s)
    for _ in range(max_ticks):
        if not thread.is_alive():
            break
        step()
        time.sleep(pace_s)
    thread.join(10.0)
    assert not thread.is_alive(), f"the {who} did not finish"
    if "error" in out:
        raise out["error"]
    return out["result"]
