"""DoIP wire format (ISO 13400-2:2012 / 2019): the generic header's checks and the payloads.

The payloads are doipclient's message classes (`doipclient.messages`: pack / unpack per payload
type); this module adds what a *server* needs and the library leaves to it: the generic header
read and checked before any payload byte is kept (ISO 13400-2:2019 §7.1.4 Figure 9, "generic
DoIP header handler": pattern, payload type, maximum size, memory, payload length, in that
order), each payload type's valid lengths, and which transport (UDP / TCP_DATA) takes it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from doipclient import messages as m

HEADER = struct.Struct("!BBHL")  # protocol version, inverse version, payload type, length
HEADER_LEN = HEADER.size
PROTOCOL_VERSIONS = (0x02, 0x03)  # ISO 13400-2:2012, ISO 13400-2:2019
DEFAULT_VERSION = 0xFF  # Table 16: only in vehicle identification requests
IDENTIFICATION_REQUESTS = (0x0001, 0x0002, 0x0003)

GenericNack = m.GenericDoIPNegativeAcknowledge.NackCodes
ActivationCode = m.RoutingActivationResponse.ResponseCode
DiagNack = m.DiagnosticMessageNegativeAcknowledgement.NackCodes  # Table 26




@dataclass(frozen=True)
class PayloadRule:
    """What the entity accepts of one payload type: the class, the valid payload lengths
    (None: at least `min_len`), and the transports it arrives on."""

    cls: Any  # a doipclient.messages class (unpack / pack)
    lengths: tuple[int, ...] | None
    udp: bool
    tcp: bool
    min_len: int = 0


# the payload types a client may send to a DoIP entity (ISO 13400-2:2019 Table 17); the
# entity's own messages (0x0000, 0x0004, 0x0006, 0x4002, 0x4004, 0x8002, 0x8003) are not in it
RULES: dict[int, PayloadRule] = {
    0x0001: PayloadRule(m.VehicleIdentificationRequest, (0,), udp=True, tcp=False),
    0x0002: PayloadRule(m.VehicleIdentificationRequestWithEID, (6,), udp=True, tcp=False),
    0x0003: PayloadRule(m.VehicleIdentificationRequestWithVIN, (17,), udp=True, tcp=False),
    0x0005: PayloadRule(m.RoutingActivationRequest, (7, 11), udp=False, tcp=True),
    0x0007: PayloadRule(m.AliveCheckRequest, (0,), udp=False, tcp=True),
    0x0008: PayloadRule(m.AliveCheckResponse, (2,), udp=False, tcp=True),
    0x4001: PayloadRule(m.DoipEntityStatusRequest, (0,), udp=True, tcp=False),
    0x4003: PayloadRule(m.DiagnosticPowerModeRequest, (0,), udp=True, tcp=False),
    0x8001: PayloadRule(m.DiagnosticMessage, None, udp=False, tcp=True, min_len=5),
}
# the entity's own answers, ignored when they arrive (its own broadcast looped back, another
# entity's announcement): a NACK to them could ping-pong between two entities
ENTITY_MESSAGES = frozenset({0x0000, 0x0004, 0x0006, 0x4002, 0x4004, 0x8002, 0x8003})


@dataclass(frozen=True)
class Header:
    version: int
    inverse: int
    payload_type: int
    length: int

    @classmethod
    def parse(cls, data: bytes | bytearray) -> Header:
        return cls(*HEADER.unpack_from(data))


def pattern_ok(h: Header) -> bool:
    """Table 16 / Figure 9: inverse = version XOR 0xFF, a supported version, 0xFF only for a
    vehicle identification request."""
    if h.inverse != h.version ^ 0xFF:
        return False
    if h.version in PROTOCOL_VERSIONS:
        return True
    return h.version == DEFAULT_VERSION and h.payload_type in IDENTIFICATION_REQUESTS


def length_ok(rule: PayloadRule, length: int) -> bool:
    return length >= rule.min_len if rule.lengths is None else length in rule.lengths


def unpack(payload_type: int, payload: bytes) -> Any:
    """The payload as doipclient's message object (the length was checked: length_ok)."""
    return RULES[payload_type].cls.unpack(payload, len(payload))


def pack(msg: Any, version: int) -> bytes:
    """A whole DoIP message: generic header (version: 2 or 3) + doipclient's packed payload."""
    body = bytes(msg.pack())
    return HEADER.pack(version, version ^ 0xFF, m.payload_message_to_type[type(msg)],
                       len(body)) + body


def generic_nack(code: int, version: int) -> bytes:
    return pack(m.GenericDoIPNegativeAcknowledge(code), version)
