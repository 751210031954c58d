"""The gateway's configuration (GATEWAY.toml, docs/gateway.md "Config file"): who the DoIP entity
is (VIN, EID, GID, logical address, ISO 13400-2 timers) and, per ECU behind it, the logical
address a tester names and the CAN side that reaches it (ISO 15765-2 addressing, IDs, P2 / P2*).

Every key is checked here, before anything opens a socket or a bus: a problem is one
GatewayConfigError line naming the file, the key and the problem, e.g.
``gw.toml: key 'ecu[1].logical_address': 0x0010 is already ecu[0]'s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from vecu.errors import BadFileError
from vecu.tomlfile import read_toml

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]  # the same API under the 3.10 backport's name

# ISO-TP's largest message with a 12-bit FF_DL (ISO 15765-2 classic CAN; can-isotp's
# max_frame_size in vecu.uds.transport): a longer UDS request gets DoIP NACK 0x04
MAX_UDS_BYTES = 4095
# ISO 13400-2 Table 13 (2019: Table 16) logical addresses: ECUs 0x0001-0x0DFF, external testers
# 0x0E00-0x0FFF, DoIP entities / further ECUs 0x1000-0x7FFF; functional 0xE400-0xE3FF..0xEFFF
ECU_ADDRESSES = (0x0001, 0x7FFF)
TESTER_ADDRESSES = (0x0E00, 0x0FFF)
FUNCTIONAL_ADDRESSES = (0xE000, 0xEFFF)
# ISO 15765-2 addressing formats a route may use: name -> (29-bit IDs, an address byte in the
# frame's first data byte, IDs derived from the address bytes (normal fixed))
ADDRESSING: dict[str, tuple[bool, bool, bool]] = {
    "normal_11bit": (False, False, False),
    "normal_29bit": (True, False, False),
    "normal_fixed_29bit": (True, False, True),
    "extended": (False, True, False),
    "extended_29bit": (True, True, False),
}
FUNCTIONAL_ADDRESSING = ("normal_11bit", "normal_29bit")
NORMAL_FIXED_PHYSICAL = 0x18DA0000  # ISO 15765-2 normal fixed: 0x18DA<N_TA><N_SA>
DEFAULT_CAN_SOURCE = 0xF1  # the tester's N_SA on CAN (normal fixed / extended addressing)


def _b(lo: float, hi: float) -> dict[str, Any]:
    return {"bounds": (lo, hi)}


@dataclass(frozen=True)
class EcuRoute:
    """One ECU behind the gateway: its DoIP logical address and its ISO-TP channel on CAN."""

    name: str
    logical_address: int = field(metadata=_b(*ECU_ADDRESSES))
    request_id: int = field(metadata=_b(0, 0x1FFFFFFF))   # the gateway sends requests here
    response_id: int = field(metadata=_b(0, 0x1FFFFFFF))  # the ECU answers here
    addressing: str = "normal_11bit"                      # a key of ADDRESSING
    target_address: int | None = field(default=None, metadata=_b(0, 0xFF))  # the ECU's N_TA
    source_address: int = field(default=DEFAULT_CAN_SOURCE, metadata=_b(0, 0xFF))  # our N_SA
    p2_ms: float = field(default=50.0, metadata=_b(1, 65535))
    p2_star_ms: float = field(default=5000.0, metadata=_b(10, 655350))

    @property
    def extended_ids(self) -> bool:
        """29-bit CAN identifiers."""
        return ADDRESSING[self.addressing][0]


@dataclass(frozen=True)
class GatewayConfig:
    """The DoIP entity and its routing table (frozen; load_gateway_config / default_config)."""

    vin: str = "1VECU00SIM0000001"
    eid: bytes = bytes.fromhex("020000001000")  # 6 bytes (a locally administered MAC)
    gid: bytes = bytes.fromhex("020000001000")
    logical_address: int = field(default=0x1000, metadata=_b(*ECU_ADDRESSES))
    tester_addresses: tuple[int, int] = TESTER_ADDRESSES  # accepted tester SAs, inclusive
    functional_address: int = field(default=0xE400, metadata=_b(*FUNCTIONAL_ADDRESSES))
    functional_id: int = field(default=0x7DF, metadata=_b(0, 0x1FFFFFFF))
    functional_addressing: str = "normal_11bit"  # normal_11bit | normal_29bit
    ecus: tuple[EcuRoute, ...] = ()
    # DoIP side (ISO 13400-2)
    protocol_version: int = field(default=2, metadata=_b(2, 3))  # 2: 2012, 3: 2019
    max_sockets: int = field(default=4, metadata=_b(1, 255))     # TCP_DATA sockets
    announce_count: int = field(default=3, metadata=_b(0, 255))  # A_DoIP_Announce_Num
    announce_interval_ms: float = field(default=500.0, metadata=_b(0, 60000))
    announce_max_delay_ms: float = field(default=500.0, metadata=_b(0, 60000))
    initial_inactivity_s: float = field(default=2.0, metadata=_b(0.001, 3600))
    general_inactivity_s: float = field(default=300.0, metadata=_b(0.001, 86400))
    alive_check_timeout_s: float = field(default=0.5, metadata=_b(0.001, 60))
    further_action: int = field(default=0x00, metadata=_b(0, 0xFF))
    power_mode: int = field(default=0x01, metadata=_b(0, 0xFF))  # 0x01: ready
    # routing activation types (0x00 default, 0x01 WWH-OBD, 0xE0 central security, 0xE1-0xFF
    # OEM) the entity accepts, and those that answer 'missing authentication' (0x04) or
    # 'confirmation rejected' (0x05)
    activation_types: tuple[int, ...] = (0x00, 0x01)
    authentication_types: tuple[int, ...] = ()
    confirmation_types: tuple[int, ...] = ()

    def route(self, logical_address: int) -> EcuRoute | None:
        return next((r for r in self.ecus if r.logical_address == logical_address), None)


def _route(name: str, la: int, req: int, resp: int) -> EcuRoute:
    return EcuRoute(name, la, req, resp)


DEFAULT_ROUTES = (_route("ecu0", 0x0010, 0x7E0, 0x7E8), _route("ecu1", 0x0011, 0x7E1, 0x7E9))

DEFAULT_TOML = '''\
# vecu gateway configuration (docs/gateway.md "Config file"). Numbers may be written in hex.
# Every key is optional; what is left out takes the value shown here. [[ecu]] tables replace
# the two shown (each needs logical_address and, except normal_fixed_29bit, both CAN IDs).

vin = "1VECU00SIM0000001"        # 17 characters, answered in vehicle identification and DID 0xF190
eid = "02:00:00:00:10:00"        # entity ID, 6 bytes (usually a MAC address)
gid = "02:00:00:00:10:00"        # group ID, 6 bytes
logical_address = 0x1000         # the gateway's own logical address (it answers UDS there)
tester_addresses = [0x0E00, 0x0FFF]   # tester source addresses routing activation accepts
functional_address = 0xE400      # a diagnostic message to it goes to every ECU on CAN ...
functional_id = 0x7DF            # ... as one single frame on this CAN ID
functional_addressing = "normal_11bit"   # or "normal_29bit"

[doip]
protocol_version = 2             # 2 (ISO 13400-2:2012) or 3 (2019) in the entity's own messages
max_sockets = 4                  # TCP_DATA sockets the entity serves at once
announce_count = 3               # vehicle announcements after start ...
announce_interval_ms = 500.0     # ... this far apart ...
announce_max_delay_ms = 500.0    # ... the first after a random 0 .. this delay
initial_inactivity_s = 2.0       # T_TCP_Initial_Inactivity: connect -> routing activation
general_inactivity_s = 300.0     # T_TCP_General_Inactivity: no traffic on an active socket
alive_check_timeout_s = 0.5      # T_TCP_Alive_Check: wait for an alive check response
further_action = 0x00            # vehicle announcement's further action code
power_mode = 0x01                # diagnostic power mode: 0x01 ready
activation_types = [0x00, 0x01]  # routing activation types accepted (0x00 default, 0x01 WWH-OBD)
authentication_types = []        # of those, types answered 0x04 (missing authentication)
confirmation_types = []          # of those, types answered 0x05 (confirmation rejected)

# One table per ECU behind the gateway.
#   addressing: normal_11bit | normal_29bit | normal_fixed_29bit | extended | extended_29bit
#   normal_fixed_29bit: IDs 0x18DA<target_address><source_address> (request) and
#     0x18DA<source_address><target_address> (response); request_id / response_id may be left out
#   extended: the first data byte of every frame is target_address (requests) or
#     source_address (responses)
#   p2_ms / p2_star_ms: how long the gateway waits for the response, and after each 0x78
[[ecu]]
name = "ecu0"
logical_address = 0x0010
request_id = 0x7E0
response_id = 0x7E8
addressing = "normal_11bit"
p2_ms = 50.0
p2_star_ms = 5000.0

[[ecu]]
name = "ecu1"
logical_address = 0x0011
request_id = 0x7E1
response_id = 0x7E9
addressing = "normal_11bit"
p2_ms = 50.0
p2_star_ms = 5000.0
'''


class GatewayConfigError(BadFileError):
    """A bad gateway config file: GatewayConfigError(path, "key 'k': problem")."""


TOP = {"vin": str, "eid": str, "gid": str, "logical_address": int, "tester_addresses": list,
       "functional_address": int, "functional_id": int, "functional_addressing": str,
       "doip": dict, "ecu": list,
       # routing between buses (vecu.gateway.routes_config reads these)
       "buses": dict, "routes": list, "deny": list}
DOIP = {f.name: list if f.name.endswith("types") else {"int": int, "float": float}[str(f.type)]
        for f in fields(GatewayConfig)
        if f.name in ("protocol_version", "max_sockets", "announce_count", "further_action",
                      "power_mode", "activation_types", "authentication_types",
                      "confirmation_types") or f.name.endswith(("_ms", "_s"))}
ECU = {"name": str, "logical_address": int, "request_id": int, "response_id": int,
       "addressing": str, "target_address": int, "source_address": int, "p2_ms": float,
       "p2_star_ms": float}
_TYPE_NAMES = {str: "a string", int: "an integer", float: "a number", bool: "true or false",
               dict: "a table", list: "an array"}


class _Check:
    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, problem: str) -> GatewayConfigError:
        return GatewayConfigError(self.path, f"key '{key}': {problem}")

    def table(self, data: Any, schema: dict[str, Any], prefix: str) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise self.fail(prefix.rstrip("."), f"expected a table, got {_tname(data)}")
        for key, value in data.items():
            want = schema.get(key)
            if want is None:
                raise self.fail(prefix + key, f"unknown key (known: {', '.join(schema)})")
            ok = (isinstance(value, (int, float)) if want is float else isinstance(value, want))
            if not ok or (isinstance(value, bool) and want is not bool):
                raise self.fail(prefix + key, f"expected {_TYPE_NAMES[want]}, got {_tname(value)}")
            if want is float and not math.isfinite(value):
                raise self.fail(prefix + key, f"expected a finite number, got {value}")
        return data

    def bounded(self, cls: type, values: dict[str, Any], prefix: str) -> None:
        """Each value inside its field's bounds (the dataclass's metadata)."""
        for f in fields(cls):
            lo_hi = f.metadata.get("bounds")
            if lo_hi is None or values.get(f.name) is None:
                continue
            value, (lo, hi) = values[f.name], lo_hi
            if not lo <= value <= hi:
                show = _hex if f.name.endswith(("address", "_id")) else str
                raise self.fail(prefix + f.name,
                                f"{show(value)} is outside {show(lo)}..{show(hi)}")

    def address_bytes(self, key: str, text: str) -> bytes:
        try:
            raw = bytes.fromhex(text.replace(":", "").replace("-", "").replace(" ", ""))
        except ValueError:
            raise self.fail(key, f"expected 6 hex bytes like 02:00:00:00:10:00, got {text!r}") \
                from None
        if len(raw) != 6:
            raise self.fail(key, f"expected 6 bytes, got {len(raw)}")
        return raw


def _tname(value: Any) -> str:
    return _TYPE_NAMES.get(type(value), type(value).__name__)


def _hex(value: int) -> str:
    return f"0x{value:04X}" if value <= 0xFFFF else f"0x{value:X}"


def load_gateway_config(path: str | Path) -> GatewayConfig:
    """Read and check GATEWAY.toml; a problem is one GatewayConfigError line (file, key)."""
    return parse_gateway_config(read_toml(path, GatewayConfigError), str(path))


def default_config() -> GatewayConfig:
    """The shipped default: DEFAULT_TOML, parsed and checked like a user's file."""
    return parse_gateway_config(tomllib.loads(DEFAULT_TOML), "<default gateway config>")


def parse_gateway_config(data: dict[str, Any], path: str) -> GatewayConfig:
    chk = _Check(path)
    chk.table(data, TOP, "")
    doip = chk.table(data.get("doip", {}), DOIP, "doip.")
    top: dict[str, Any] = {k: v for k, v in data.items()
                           if k not in ("doip", "ecu", "eid", "gid", "tester_addresses", "buses",
                                         "routes", "deny")}
    vin = top.get("vin", GatewayConfig.vin)
    if len(vin) != 17 or not vin.isascii() or not vin.isprintable():
        raise chk.fail("vin", f"expected 17 printable ASCII characters, got {len(vin)}: {vin!r}")
    for key in ("eid", "gid"):
        if key in data:
            top[key] = chk.address_bytes(key, data[key])
    if "tester_addresses" in data:
        pair = data["tester_addresses"]
        if len(pair) != 2 or not all(isinstance(a, int) and not isinstance(a, bool)
                                     for a in pair):
            raise chk.fail("tester_addresses", f"expected [first, last] integers, got {pair}")
        if not 0 <= pair[0] <= pair[1] <= 0xFFFF:
            raise chk.fail("tester_addresses",
                           f"expected first <= last in 0x0000..0xFFFF, got {pair}")
        top["tester_addresses"] = (pair[0], pair[1])
    if top.get("functional_addressing", "normal_11bit") not in FUNCTIONAL_ADDRESSING:
        raise chk.fail("functional_addressing", f"expected one of "
                       f"{', '.join(FUNCTIONAL_ADDRESSING)}, got {top['functional_addressing']!r}")
    for key in ("activation_types", "authentication_types", "confirmation_types"):
        if key in doip:
            kinds = doip[key]
            if not all(isinstance(k, int) and not isinstance(k, bool) and 0 <= k <= 0xFF
                       for k in kinds):
                raise chk.fail(f"doip.{key}", f"expected activation types 0x00..0xFF, got {kinds}")
            doip[key] = tuple(kinds)
    for key in ("authentication_types", "confirmation_types"):
        extra = set(doip.get(key, ())) - set(doip.get("activation_types",
                                                      GatewayConfig.activation_types))
        if extra:
            raise chk.fail(f"doip.{key}", f"{sorted(extra)} not in doip.activation_types")
    for key, want in DOIP.items():
        if want is float and key in doip:
            doip[key] = float(doip[key])
    chk.bounded(GatewayConfig, top, "")
    chk.bounded(GatewayConfig, doip, "doip.")
    values = {**top, **doip}
    ecus = data.get("ecu", [] if "ecu" in data else None)
    routes = DEFAULT_ROUTES if ecus is None else tuple(
        _ecu(chk, item, i) for i, item in enumerate(ecus))
    config = GatewayConfig(**values, ecus=routes)
    _check_table(chk, config)
    return config


def _ecu(chk: _Check, item: Any, i: int) -> EcuRoute:
    prefix = f"ecu[{i}]."
    chk.table(item, ECU, prefix)
    for key in ("logical_address", "request_id", "response_id"):
        if key not in item and not (key != "logical_address"
                                    and item.get("addressing") == "normal_fixed_29bit"):
            raise chk.fail(prefix + key, "required key missing")
    values = dict(item)
    values.setdefault("name", f"ecu{i}")
    mode = values.get("addressing", "normal_11bit")
    if mode not in ADDRESSING:
        raise chk.fail(prefix + "addressing", f"expected one of {', '.join(ADDRESSING)}, "
                                              f"got {mode!r}")
    chk.bounded(EcuRoute, values, prefix)
    wide, prefixed, fixed = ADDRESSING[mode]
    if (prefixed or fixed) and "target_address" not in values:
        raise chk.fail(prefix + "target_address", f"required with addressing {mode!r}")
    if fixed:  # the IDs follow from the address bytes
        ta, sa = values["target_address"], values.get("source_address", DEFAULT_CAN_SOURCE)
        derived = {"request_id": NORMAL_FIXED_PHYSICAL | ta << 8 | sa,
                   "response_id": NORMAL_FIXED_PHYSICAL | sa << 8 | ta}
        for key, can_id in derived.items():
            if values.setdefault(key, can_id) != can_id:
                raise chk.fail(prefix + key, f"{_hex(values[key])} is not {_hex(can_id)}, the "
                                             f"normal fixed ID of its address bytes")
    elif not wide:
        for key in ("request_id", "response_id"):
            if values[key] > 0x7FF:
                wide_mode = "extended_29bit" if prefixed else "normal_29bit"
                raise chk.fail(prefix + key, f"{_hex(values[key])} is not an 11-bit ID "
                                             f"(addressing {mode!r}; 29-bit IDs: {wide_mode!r})")
    values["p2_ms"] = float(values.get("p2_ms", EcuRoute.p2_ms))
    values["p2_star_ms"] = float(values.get("p2_star_ms", EcuRoute.p2_star_ms))
    if values["p2_star_ms"] < values["p2_ms"]:
        raise chk.fail(prefix + "p2_star_ms", f"{values['p2_star_ms']:g} ms is shorter than "
                                              f"p2_ms ({values['p2_ms']:g} ms)")
    return EcuRoute(**values)


def _check_table(chk: _Check, cfg: GatewayConfig) -> None:
    """No two routes share a logical address, a name or a CAN channel; none is the gateway's,
    a tester's or the functional address; no route listens where another sends."""
    seen: dict[Any, str] = {}
    lo, hi = cfg.tester_addresses
    for i, r in enumerate(cfg.ecus):
        key = f"ecu[{i}]"
        if r.logical_address == cfg.logical_address:
            raise chk.fail(f"{key}.logical_address", f"{_hex(r.logical_address)} is the "
                                                     f"gateway's own logical_address")
        if lo <= r.logical_address <= hi:
            raise chk.fail(f"{key}.logical_address", f"{_hex(r.logical_address)} is in the "
                                                     f"tester_addresses range")
        byte = r.target_address if ADDRESSING[r.addressing][1] else None
        src = r.source_address if ADDRESSING[r.addressing][1] else None
        for field_name, ident in (("name", ("name", r.name)),
                                  ("logical_address", ("la", r.logical_address)),
                                  ("request_id", ("id", r.request_id, r.extended_ids, byte)),
                                  ("response_id", ("id", r.response_id, r.extended_ids, src))):
            if ident in seen:
                raise chk.fail(f"{key}.{field_name}", f"{_show(ident)} is already "
                                                      f"{seen[ident]}'s")
            seen[ident] = key
        if r.request_id == r.response_id:
            raise chk.fail(f"{key}.response_id", "equals its request_id")
    if lo <= cfg.logical_address <= hi:
        raise chk.fail("logical_address", f"{_hex(cfg.logical_address)} is in the "
                                          f"tester_addresses range")
    fid = ("id", cfg.functional_id, cfg.functional_addressing == "normal_29bit", None)
    if fid in seen:
        raise chk.fail("functional_id", f"{_hex(cfg.functional_id)} is already {seen[fid]}'s")
    if cfg.functional_addressing == "normal_11bit" and cfg.functional_id > 0x7FF:
        raise chk.fail("functional_id", f"{_hex(cfg.functional_id)} is not an 11-bit ID")


def _show(ident: tuple) -> str:
    return str(ident[1]) if ident[0] == "name" else _hex(ident[1])
