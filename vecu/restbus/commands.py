"""Live disturbance commands: the RB_Command frame (dbc/vecu.dbc, 0x6F2) that `vecu inject
--restbus` sends and a running `vecu restbus` obeys.

The target message is named by its CAN ID and frame format, its signal by a 1-based index
(0: the whole message), the kind by its FI_EvKind code (vecu.restbus.disturb.KINDS), and the
value by the top 21 bits of its IEEE float32 (sign, exponent, 12 mantissa bits: about 4
significant digits, every magnitude).
"""

from __future__ import annotations

import logging
import struct

import can
import numpy as np

from vecu.bus import BusNode, RxBudget
from vecu.codec import FrameCodec, shared_codec
from vecu.errors import BadArgumentError
from vecu.restbus import disturb
from vecu.restbus.node import RestbusNode

_DROP_BITS = 11
_F32 = struct.Struct(">f")
_U32 = struct.Struct(">I")
_CODES = {k.code: name for name, k in disturb.KINDS.items()}
_log = logging.getLogger("vecu.restbus")


def value_bits(value: float) -> int:
    """value as RB_ValueBits (rounded to the nearest of the 21-bit floats)."""
    bits = _U32.unpack(_F32.pack(value))[0]
    return min((bits + (1 << (_DROP_BITS - 1))) >> _DROP_BITS, (1 << 21) - 1)


def bits_value(bits: int) -> float:
    return _F32.unpack(_U32.pack(bits << _DROP_BITS))[0]


def command_frame(frame_id: int, extended: bool, signal_index: int, kind: str, active: bool,
                  value: float | None) -> can.Message:
    """The RB_Command frame for one disturbance start (active) or end."""
    k = disturb.KINDS.get(kind)
    if k is None and kind != "clear":
        raise BadArgumentError(f"unknown restbus disturbance {kind!r} (known: "
                               f"{', '.join(disturb.KINDS)}, clear)")
    if not 0 <= signal_index <= 63:
        raise BadArgumentError(f"RB_Command addresses signals 1..63, not {signal_index}")
    v = (0.0 if k is None else k.default) if value is None else value
    return shared_codec()["RB_Command"].frame({
        "RB_MessageId": frame_id, "RB_Extended": int(extended), "RB_Active": int(active),
        "RB_Kind": 0 if k is None else k.code, "RB_Signal": signal_index,
        "RB_ValueBits": value_bits(v)}, 0.0)


def command_for(databases: tuple[str, ...], target: str, kind: str,
                value: float | None) -> can.Message:
    """The RB_Command for `vecu inject --restbus DB… --target MESSAGE[.SIGNAL] --kind K`
    (K 'clear': every disturbance of the message ends); names checked against the databases."""
    from vecu.codec import DbcCodec

    db = DbcCodec(databases, strict=False)
    msg, _, sig = target.strip().partition(".")
    if msg not in db:
        raise BadArgumentError(f"--target {target!r}: no message {msg!r} in "
                               f"{', '.join(databases)}")
    fc = db[msg]
    names = [s.name for s in fc.signals]
    if sig and sig not in names:
        raise BadArgumentError(f"--target {target!r}: message {msg} has no signal {sig!r}")
    index = names.index(sig) + 1 if sig else 0
    if kind == "clear":  # RB_Kind 0, RB_Active 0: every disturbance of the message ends
        return command_frame(fc.frame_id, fc.is_extended, index, "clear", False, None)
    disturb.make(kind, value, np.random.default_rng(0), sig or None)  # the restbus's own check
    return command_frame(fc.frame_id, fc.is_extended, index, kind, True, value)


# frames read per 10 ms poll at most (~3x a saturated 1 Mbit/s bus); the rest waits in the bus
POLL_BUDGET = RxBudget(frames_per_tick=640, shed_per_tick=0)


class CommandListener(BusNode):
    """Reads the restbus's bus every poll (a scheduler task), at most POLL_BUDGET frames, and
    applies RB_Command frames; a command that makes the handler fail is counted
    (handler_errors), never raised."""

    def __init__(self, node: RestbusNode, bus: can.BusABC) -> None:
        super().__init__(bus, "restbus", rx_budget=POLL_BUDGET)
        self.node = node
        self.codec: FrameCodec = shared_codec()["RB_Command"]
        self.applied = 0
        self.rejected = 0

    def poll(self, t_ns: int) -> None:
        recv, key = self.bus.recv, self.codec.frame_id
        for _ in range(self.rx_budget.frames_per_tick):
            msg = recv(0.0)
            if msg is None:
                return
            if msg.arbitration_id == key and not msg.is_extended_id:
                try:
                    self.apply(t_ns, msg)
                except Exception as exc:  # noqa: BLE001 - the handler boundary: counted
                    self.rejected += 1
                    self.handler_failed("RB_Command", exc)

    def apply(self, t_ns: int, msg: can.Message) -> bool:
        try:
            v = self.codec.decode(msg.data)
            code = int(v["RB_Kind"])
            can_id, ext = int(v["RB_MessageId"]), bool(v["RB_Extended"])
            i = next(j for j, p in enumerate(self.node.plans)
                     if p.codec.frame_id == can_id and p.codec.is_extended == ext)
            plan = self.node.plans[i]
            target = plan.name
            index = int(v["RB_Signal"])
            if index:
                target += "." + plan.codec.signals[index - 1].name
            if v["RB_Active"]:
                self.node.disturb(t_ns, target, _CODES[code], bits_value(int(v["RB_ValueBits"])),
                                  source="can")
            else:  # RB_Kind 0: every disturbance of the message
                self.node.clear(t_ns, target, _CODES[code] if code else None, source="can")
        except (KeyError, StopIteration, IndexError, ValueError) as exc:
            self.rejected += 1
            _log.warning("restbus: RB_Command %s refused: %s", bytes(msg.data).hex(), exc)
            return False
        self.applied += 1
        return True
