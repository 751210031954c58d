"""pytest fixtures for a user's tests against vecu (entry point `pytest11`, loaded by pytest
when vecu is installed; docs/python.md).

- `vecu_rig`: a VecuRig. `rig.start(duration_s, **options)` runs plant + fault injector + ECU
  (the options of `vecu.simulate`) on the wall clock in a background thread, on a private bus:
  python-can's `virtual` interface on a channel of its own (default), or `--vecu-interface
  udp_multicast` / `socketcan` with `--vecu-channel`. `rig.bus()` opens a bus to it, `rig.wait()`
  returns the typed run summary.
- `vecu_tester`: a udsoncan Client over ISO-TP (can-isotp) to the rig's ECU, started with the
  defaults when the test has not started it.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import can
import pytest

from vecu.bus import open_bus
from vecu.clock import monotonic_ns

if TYPE_CHECKING:
    from vecu.config import RunConfig
    from vecu.runner import RunResult
    from vecu.summary import RunSummary

START_TIMEOUT_S = 60.0  # the first ECU frame on the bus (kernels load first)


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("vecu")
    group.addoption("--vecu-interface", default="virtual",
                    help="python-can interface of vecu_rig's bus (default: virtual, in process)")
    group.addoption("--vecu-channel", default=None,
                    help="its channel (default: a private virtual channel per test)")


class VecuRig:
    """Plant + ECU on a private bus in a background thread (see the module docstring)."""

    def __init__(self, interface: str, channel: str) -> None:
        self.interface, self.channel = interface, channel
        self.config: RunConfig | None = None
        self._result: RunResult | None = None
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._buses: list[can.BusABC] = []

    def start(self, duration_s: float = 5.0, **options: Any) -> RunConfig:
        """Run vecu.simulate's options on the wall clock; returns once the ECU's first frame is
        on the bus. kill_tps_at_s defaults to None here (no fault unless the test asks)."""
        from vecu.runner import run
        from vecu.simulation import run_config

        options.setdefault("kill_tps_at_s", None)
        self.config = config = run_config(duration_s, realtime=True, interface=self.interface,
                                          channel=self.channel, **options)
        listener = self.bus()
        status_id = self._status_id(config)

        def target() -> None:
            try:
                self._result = run(config)
            except BaseException as exc:  # noqa: BLE001 - re-raised in the test by wait()
                self._error = exc

        self._thread = threading.Thread(target=target, name="vecu-rig", daemon=True)
        self._thread.start()
        deadline = monotonic_ns() + round(START_TIMEOUT_S * 1e9)
        while monotonic_ns() < deadline and self._thread.is_alive():
            msg = listener.recv(timeout=0.1)
            if msg is not None and msg.arbitration_id == status_id:
                return config
        self.wait()  # raises the run's error, if any
        raise TimeoutError(f"vecu_rig: no ECU frame within {START_TIMEOUT_S:g} s")

    @staticmethod
    def _status_id(config: RunConfig) -> int:
        from vecu.functions import function_codec

        return function_codec(config.params.ecu.instance, config)["ECU_Status"].frame_id

    def bus(self) -> can.BusABC:
        """A new bus on the rig's channel (shut down at the end of the test)."""
        bus = open_bus(interface=self.interface, channel=self.channel)
        self._buses.append(bus)
        return bus

    def wait(self, timeout: float | None = None) -> RunSummary:
        """The run's typed summary once it has ended (its error, if it raised one)."""
        if self._thread is None:
            raise RuntimeError("vecu_rig: start() it first")
        self._thread.join(timeout)
        if self._error is not None:
            raise self._error
        if self._result is None:
            raise TimeoutError("vecu_rig: the run has not ended")
        return self._result.report

    def close(self) -> None:
        if self._thread is not None:
            self._thread.join()
        for bus in self._buses:
            bus.shutdown()


@pytest.fixture
def vecu_rig(request: pytest.FixtureRequest) -> Iterator[VecuRig]:
    """Plant + ECU on a private bus (start() it with vecu.simulate's options)."""
    interface = request.config.getoption("--vecu-interface")
    channel = request.config.getoption("--vecu-channel") or f"vecu-test-{uuid.uuid4().hex[:12]}"
    rig = VecuRig(interface, channel)
    yield rig
    rig.close()


@pytest.fixture
def vecu_tester(vecu_rig: VecuRig) -> Iterator[Any]:
    """A udsoncan Client (ISO-TP, the ECU's UDS IDs) on vecu_rig's bus, open for the test."""
    from udsoncan.client import Client

    from vecu.uds.transport import tester_connection

    config = vecu_rig.config or vecu_rig.start()
    uds = config.params.ecu.uds
    with Client(tester_connection(vecu_rig.bus(), uds.request_id, uds.response_id),
                request_timeout=2.0) as client:
        yield client
