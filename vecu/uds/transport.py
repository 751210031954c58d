"""ISO-TP (ISO 15765-2) on vecu's clock: can-isotp's transport layer, driven per tick.

can-isotp does the transport (segmentation, flow control, STmin, timeouts); vecu feeds it the
frames the node received and sends what it produces. Its timers read the time through
`now_ns` (the ECU's tick time, or the scenario tester's), not the host's clock, so a request
is served the same way on the simulated clock in every run.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from typing import Any

import can
import isotp
from isotp.tools import Timer

NowNs = Callable[[], int]

# ISO-TP parameters of both ends (can-isotp names); padding 0xCC is the usual filler byte.
ISOTP_PARAMS: dict[str, Any] = {
    "stmin": 0, "blocksize": 0, "tx_padding": 0xCC, "tx_data_length": 8,
    "rx_flowcontrol_timeout": 1000, "rx_consecutive_frame_timeout": 1000,
    "max_frame_size": 4095, "blocking_send": False,
    # can-isotp logs every bad frame at WARNING: a flood of them floods the log; vecu counts
    # them (UdsStats.transport_errors) and logs the first 20 itself
    "logger_name": "vecu.uds.isotp",
}
logging.getLogger("vecu.uds.isotp").setLevel(logging.ERROR)


class ClockTimer(Timer):
    """can-isotp's Timer on a given time source (integer ns)."""

    def __init__(self, timeout: float, now_ns: NowNs) -> None:
        self._now_ns = now_ns
        super().__init__(timeout)

    def start(self, timeout: float | None = None) -> None:
        if timeout is not None:
            self.set_timeout(timeout)
        self.start_time = self._now_ns()

    def elapsed_ns(self) -> int:
        return 0 if self.start_time is None else self._now_ns() - self.start_time

    def elapsed(self) -> float:
        return self.elapsed_ns() / 1e9


class ClockedTransport(isotp.TransportLayerLogic):
    """can-isotp's non-threaded transport layer with its timers on `now_ns`."""

    def __init__(self, rxfn: Callable[[float], isotp.CanMessage | None],
                 txfn: Callable[[isotp.CanMessage], None], address: isotp.Address,
                 now_ns: NowNs, params: dict[str, Any] | None = None,
                 error_handler: Callable[[Exception], None] | None = None) -> None:
        self._now_ns = now_ns  # before the base class: its __init__ calls load_params()
        super().__init__(rxfn, txfn, address, error_handler=error_handler,
                         params={**ISOTP_PARAMS, **(params or {})})
        self.timer_tx_stmin = ClockTimer(0, now_ns)

    def load_params(self) -> None:
        super().load_params()
        self.timer_rx_fc = ClockTimer(self.params.rx_flowcontrol_timeout / 1000, self._now_ns)
        self.timer_rx_cf = ClockTimer(self.params.rx_consecutive_frame_timeout / 1000,
                                      self._now_ns)

    def _start_rx_fc_timer(self) -> None:
        self.timer_rx_fc = ClockTimer(self.params.rx_flowcontrol_timeout / 1000, self._now_ns)
        self.timer_rx_fc.start()

    def _start_rx_cf_timer(self) -> None:
        self.timer_rx_cf = ClockTimer(self.params.rx_consecutive_frame_timeout / 1000,
                                      self._now_ns)
        self.timer_rx_cf.start()


def to_isotp(msg: can.Message) -> isotp.CanMessage:
    return isotp.CanMessage(arbitration_id=msg.arbitration_id, data=bytes(msg.data),
                            dlc=len(msg.data), extended_id=msg.is_extended_id)


def to_can(msg: isotp.CanMessage, timestamp: float = 0.0) -> can.Message:
    return can.Message(arbitration_id=msg.arbitration_id, data=msg.data,
                       is_extended_id=msg.is_extended_id, timestamp=timestamp)


class Endpoint:
    """One ISO-TP end: frames in (put()), payloads out (requests()), frames out (drain()).

    rx_id: the CAN ID it listens on; tx_id: where it sends (and the flow control of what it
    receives). Frames it produces wait in a queue until drain() hands them to the bus.
    `address`, when given, replaces the normal addressing of rx_id / tx_id (another ISO 15765-2
    addressing format: normal fixed, extended, as can-isotp's Address has them)."""

    def __init__(self, rx_id: int, tx_id: int, now_ns: NowNs, extended: bool = False,
                 errors: Callable[[Exception], None] | None = None,
                 params: dict[str, Any] | None = None,
                 address: isotp.Address | None = None) -> None:
        mode = isotp.AddressingMode.Normal_29bits if extended else isotp.AddressingMode.Normal_11bits
        self._in: deque[isotp.CanMessage] = deque()
        self.out: deque[isotp.CanMessage] = deque()
        self.layer = ClockedTransport(self._rx, self.out.append,
                                      address or isotp.Address(mode, rxid=rx_id, txid=tx_id),
                                      now_ns, params=params, error_handler=errors)

    def _rx(self, timeout: float) -> isotp.CanMessage | None:
        return self._in.popleft() if self._in else None

    def put(self, msg: can.Message) -> None:
        self._in.append(to_isotp(msg))

    @property
    def frames_in(self) -> int:
        """Frames put and not yet taken in by process()."""
        return len(self._in)

    def process(self) -> None:
        """Take in every frame put so far. can-isotp's process() stops at a frame that wants
        an immediate transmission (a flow control to send, or one received while idle): called
        once, it left the rest for the next tick, 1 frame a tick under a stream of such frames."""
        for _ in range(len(self._in) + 1):
            self.layer.process()
            if not self._in:
                break

    def send(self, payload: bytes, functional: bool = False) -> None:
        self.layer.send(payload, isotp.TargetAddressType.Functional if functional else None)

    def payloads(self) -> list[bytes]:
        out = []
        while (data := self.layer.recv()) is not None:
            out.append(bytes(data))
        return out

    @property
    def busy(self) -> bool:
        return bool(self._in or self.out) or self.layer.transmitting() \
            or self.layer.rx_state != self.layer.RxState.IDLE


def tester_connection(bus: can.BusABC, request_id: int, response_id: int) -> Any:
    """A tester's end on a live bus: can-isotp's threaded CanStack (normal 11-bit addressing,
    its default parameters) in udsoncan's PythonIsoTpConnection, opened; close() it."""
    from udsoncan.connections import PythonIsoTpConnection

    stack = isotp.CanStack(bus, address=isotp.Address(
        isotp.AddressingMode.Normal_11bits, txid=request_id, rxid=response_id))
    conn = PythonIsoTpConnection(stack)
    conn.open()
    return conn
