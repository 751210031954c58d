"""python-can Message objects made without can.Message.__init__'s argument handling.

A frame vecu encodes (FrameCodec.frame) or copies for a log writer on the in-process lane
(bus.LaneBus) has known, valid fields; can.Message.__init__ spends ~1.5 us on keyword parsing and
conversions, setting the slots directly ~0.5 us. The result is a real can.Message with the same
field values and types as can.Message(..., check=False) gives. At import the two are compared
on sample frames; if this python-can's Message has other slots or defaults, every call falls
back to can.Message itself.
"""

from __future__ import annotations

import can

FIELDS = frozenset({"timestamp", "arbitration_id", "is_extended_id", "is_remote_frame",
                     "is_error_frame", "channel", "dlc", "data", "is_fd", "is_rx",
                     "bitrate_switch", "error_state_indicator"})
_new = object.__new__
_Message = can.Message
# a message's signal values in the DBC's order (None: a multiplexed signal a frame lacks), as a
# codec framer gives them beside its frame and a node's estimate sinks take them
Values = tuple[float | None, ...]


def _direct(timestamp: float, arbitration_id: int, is_extended_id: bool,
            data: bytes | bytearray, is_fd: bool = False, channel: object = None,
            is_rx: bool = True, is_remote_frame: bool = False, is_error_frame: bool = False,
            dlc: int | None = None, bitrate_switch: bool = False,
            error_state_indicator: bool = False) -> can.Message:
    m = _new(_Message)
    m.timestamp = timestamp
    m.arbitration_id = arbitration_id
    m.is_extended_id = is_extended_id
    m.is_remote_frame = is_remote_frame
    m.is_error_frame = is_error_frame
    m.channel = channel
    m.data = data if type(data) is bytearray else bytearray(data)
    m.dlc = len(m.data) if dlc is None else dlc
    m.is_fd = is_fd
    m.is_rx = is_rx
    m.bitrate_switch = bitrate_switch
    m.error_state_indicator = error_state_indicator
    return m


def _reference(timestamp: float, arbitration_id: int, is_extended_id: bool,
               data: bytes | bytearray, is_fd: bool = False, channel: object = None,
               is_rx: bool = True, is_remote_frame: bool = False, is_error_frame: bool = False,
               dlc: int | None = None, bitrate_switch: bool = False,
               error_state_indicator: bool = False) -> can.Message:
    return _Message(timestamp=timestamp, arbitration_id=arbitration_id,
                    is_extended_id=is_extended_id, is_remote_frame=is_remote_frame,
                    is_error_frame=is_error_frame, channel=channel, dlc=dlc, data=data,
                    is_fd=is_fd, is_rx=is_rx, bitrate_switch=bitrate_switch,
                    error_state_indicator=error_state_indicator, check=False)


SAMPLES: tuple[dict, ...] = (
    {"timestamp": 1.5, "arbitration_id": 0x123, "is_extended_id": False, "data": b"\x01\x02"},
    {"timestamp": 0.0, "arbitration_id": 0x1ABCDEF, "is_extended_id": True,
     "data": bytearray(8), "channel": "vecu", "is_rx": False},
    {"timestamp": 2.0, "arbitration_id": 0x7FF, "is_extended_id": False, "data": bytes(12),
     "is_fd": True, "bitrate_switch": True, "error_state_indicator": True},
    {"timestamp": 3.0, "arbitration_id": 0x100, "is_extended_id": False, "data": b"",
     "is_remote_frame": True, "dlc": 4},
    {"timestamp": 4.0, "arbitration_id": 0, "is_extended_id": False, "data": b"",
     "is_error_frame": True},
)


def same_message(a: can.Message, b: can.Message) -> bool:
    """Every field of a and b equal, with the same types."""
    return all(getattr(a, f) == getattr(b, f) and type(getattr(a, f)) is type(getattr(b, f))
               for f in FIELDS)


def _verified() -> bool:
    if set(_Message.__slots__) - {"__weakref__"} != FIELDS:
        return False
    try:
        return all(same_message(_direct(**s), _reference(**s)) for s in SAMPLES)
    except Exception:  # noqa: BLE001 - anything unexpected: python-can's own constructor
        return False


DIRECT = _verified()
message = _direct if DIRECT else _reference  # message(timestamp, arbitration_id, ...)

