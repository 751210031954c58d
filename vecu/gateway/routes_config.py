"""Routing between CAN buses, as the gateway config file names it (docs/gateway.md "Routing
between buses"): `[buses.NAME]` (python-can arguments and the bus's databases), `[[routes]]`
(frame routes: messages / ids / id+mask copied, optionally to a new ID, at most one frame per
min_interval_ms; signal routes: signals unpacked from source messages and repacked into one target
message, E2E-protected as its new sender) and `[[deny]]` (the firewall).

Every problem is one GatewayConfigError line naming the file, the key and the problem, before any
bus opens (routes_check holds the checks across routes: loops, two writers of a signal).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vecu.codec import DEFAULT_DBC, TRUTH_DBC, DbcCodec, builtin_dbc_path
from vecu.e2e import E2EConfigError, E2EProtection
from vecu.errors import BadFileError
from vecu.gateway.config import GatewayConfigError, _Check, _hex
from vecu.gateway.routes import BusSpec, DenyRule, FrameRoute, RoutingConfig, SignalMap, SignalRoute
from vecu.gateway.routes_check import check_routes
from vecu.gateway.signal_routes import source_protection
from vecu.tomlfile import read_toml
from vecu.units import DEG_PER_RAD, KELVIN_AT_0_DEGC, KMH_PER_MPS, MPS_PER_KMH, RAD_PER_DEG

SHIPPED_DBCS = {"vecu": DEFAULT_DBC, "vecu_truth": TRUTH_DBC}  # dbc = ["vecu"]: by name
SEND_MODES = ("cyclic", "on_change", "both")
# unit conversions a signal route makes (source unit, target unit) -> (factor, offset):
# target = source * factor + offset; the same unit, or a unit left empty, is taken as is
UNIT_CONVERSIONS: dict[tuple[str, str], tuple[float, float]] = {
    ("km/h", "m/s"): (MPS_PER_KMH, 0.0), ("m/s", "km/h"): (KMH_PER_MPS, 0.0),
    ("deg", "rad"): (RAD_PER_DEG, 0.0), ("rad", "deg"): (DEG_PER_RAD, 0.0),
    ("degC", "K"): (1.0, KELVIN_AT_0_DEGC), ("K", "degC"): (1.0, -KELVIN_AT_0_DEGC),
}
BUS = {"interface": str, "channel": str, "bitrate": int, "fd": bool, "data_bitrate": int,
       "port": int, "dbc": list}
ROUTE = {"from": str, "to": str, "messages": list, "ids": list, "id": int, "mask": int,
         "min_interval_ms": float, "target": str, "send": str, "timeout_ms": float,
         "signals": dict, "e2e": dict, "delay_ms": float, "e2e_check": bool}
E2E = {"profile": str, "data_id": int, "data_id_list": list, "data_id_mode": str, "offset": int,
       "length": int}
DENY = {"from": str, "ids": list}


def load_routing_config(path: str | Path) -> RoutingConfig:
    """The routing half of GATEWAY.toml, checked (one GatewayConfigError line on a problem)."""
    return parse_routing_config(read_toml(path, GatewayConfigError), str(path))


def parse_routing_config(data: dict[str, Any], path: str) -> RoutingConfig:
    chk = _Check(path)
    base = Path(path).parent
    raw_buses = data.get("buses", {})
    if not isinstance(raw_buses, dict):
        raise chk.fail("buses", "expected a table of [buses.NAME] tables")
    buses = tuple(_bus(chk, name, item, base) for name, item in raw_buses.items())
    by_name = {b.name: b for b in buses}
    frames: list[FrameRoute] = []
    signals: list[SignalRoute] = []
    for i, item in enumerate(_array(chk, data, "routes")):
        key = f"routes[{i}]"
        chk.table(item, ROUTE, key + ".")
        src, dst = (_bus_ref(chk, by_name, item, key, end) for end in ("from", "to"))
        if src.name == dst.name:
            raise chk.fail(f"{key}.to", f"routes to the bus it comes from ({src.name!r})")
        if "target" in item or "signals" in item:
            signals.append(_signal_route(chk, item, key, src, dst))
        else:
            frames.append(_frame_route(chk, item, key, src, dst))
    deny = tuple(_deny(chk, item, f"deny[{i}]", by_name)
                 for i, item in enumerate(_array(chk, data, "deny")))
    config = RoutingConfig(buses, tuple(frames), tuple(signals), deny)
    check_routes(chk, config)
    return config


def _array(chk: _Check, data: dict[str, Any], key: str) -> list[Any]:
    items = data.get(key, [])
    if not isinstance(items, list):
        raise chk.fail(key, f"expected an array of tables ([[{key}]])")
    return items


def _bus(chk: _Check, name: str, item: Any, base: Path) -> BusSpec:
    key = f"buses.{name}"
    chk.table(item, BUS, key + ".")
    dbcs = item.get("dbc", [])
    if not dbcs or not all(isinstance(d, str) for d in dbcs):
        raise chk.fail(f"{key}.dbc", "expected a list of database paths or shipped names "
                                     f"({', '.join(SHIPPED_DBCS)})")
    paths = [builtin_dbc_path(SHIPPED_DBCS[d]) if d in SHIPPED_DBCS else base / d for d in dbcs]
    try:
        codec = DbcCodec(paths)
    except BadFileError as exc:
        raise chk.fail(f"{key}.dbc", str(exc)) from None
    args = tuple((k, v) for k, v in item.items() if k != "dbc")
    return BusSpec(name, args, codec)


def _bus_ref(chk: _Check, buses: dict[str, BusSpec], item: dict, key: str, end: str) -> BusSpec:
    name = item.get(end)
    if name is None:
        raise chk.fail(f"{key}.{end}", "required key missing")
    if name not in buses:
        raise chk.fail(f"{key}.{end}", f"unknown bus {name!r} (buses: {', '.join(buses) or 'none'})")
    return buses[name]


def _ms(chk: _Check, item: dict, name: str, key: str) -> int:
    value = item.get(name, 0)
    if value < 0:
        raise chk.fail(f"{key}.{name}", f"expected >= 0, got {value}")
    return round(value * 1_000_000)


def _frame_route(chk: _Check, item: dict, key: str, src: BusSpec, dst: BusSpec) -> FrameRoute:
    for bad in ("send", "timeout_ms", "e2e"):  # (e2e_check: frame routes only)
        if bad in item:
            raise chk.fail(f"{key}.{bad}", "belongs to a signal route (one with target/signals)")
    ids: set[tuple[int, bool]] = set()
    for name in item.get("messages", []):
        if name not in src.codec:
            raise chk.fail(f"{key}.messages", f"unknown message {name!r} on bus {src.name!r}")
        fc = src.codec[name]
        ids.add((fc.frame_id, fc.is_extended))
    for can_id in item.get("ids", []):
        if not isinstance(can_id, int) or not 0 <= can_id <= 0x1FFFFFFF:
            raise chk.fail(f"{key}.ids", f"expected CAN IDs 0..0x1FFFFFFF, got {can_id!r}")
        ids.add((can_id, can_id > 0x7FF))
    for name in ("id", "mask"):
        if not 0 <= item.get(name, 0) <= 0x1FFFFFFF:
            raise chk.fail(f"{key}.{name}", f"{_hex(item[name])} is outside 0..0x1FFFFFFF")
    id_mask = None
    if "mask" in item:
        id_mask = (item.get("id", 0), item["mask"])
    new_id = item.get("id") if id_mask is None else None
    if not ids and id_mask is None:
        raise chk.fail(key, "a frame route needs messages, ids, or id with mask")
    if new_id is not None and len(ids) != 1:
        raise chk.fail(f"{key}.id", f"a new ID needs exactly one message, the route has {len(ids)}")
    e2e_check = bool(item.get("e2e_check", False))
    if e2e_check and not any(key_ in src.codec.by_id and source_protection(src.codec.by_id[key_])
                             for key_ in ids):
        raise chk.fail(f"{key}.e2e_check", "no message of the route names an E2E protection in "
                                           f"the databases of bus {src.name!r}")
    return FrameRoute(key, src.name, dst.name, frozenset(ids), id_mask, new_id,
                      _ms(chk, item, "min_interval_ms", key), _ms(chk, item, "delay_ms", key),
                      e2e_check)


def _signal_route(chk: _Check, item: dict, key: str, src: BusSpec, dst: BusSpec) -> SignalRoute:
    for bad in ("messages", "ids", "mask", "id", "e2e_check"):
        if bad in item:
            raise chk.fail(f"{key}.{bad}", "belongs to a frame route (signal routes name target)")
    target = item.get("target")
    if target is None:
        raise chk.fail(f"{key}.target", "required key missing")
    if target not in dst.codec:
        raise chk.fail(f"{key}.target", f"unknown message {target!r} on bus {dst.name!r}")
    fc = dst.codec[target]
    send = item.get("send", "cyclic")
    if send not in SEND_MODES:
        raise chk.fail(f"{key}.send", f"expected one of {', '.join(SEND_MODES)}, got {send!r}")
    if send != "on_change" and not fc.cycle_time_ms:
        raise chk.fail(f"{key}.send", f"{target} has no cycle time in its database: "
                                      "send = \"on_change\"")
    maps = tuple(_signal_map(chk, f"{key}.signals.{t}", src, fc, t, s)
                 for t, s in item.get("signals", {}).items())
    if not maps:
        raise chk.fail(f"{key}.signals", "expected at least one TARGET = \"MESSAGE.SIGNAL\"")
    e2e = _e2e(chk, item, key, fc, maps) if "e2e" in item else None
    mux: dict[str, int] = {}
    for m in maps:
        if m.target in fc.mux_of:
            selector, values = fc.mux_of[m.target]
            if mux.setdefault(selector, values[0]) not in values:
                raise chk.fail(f"{key}.signals.{m.target}", f"needs {selector} in {list(values)}, "
                                                           f"another target needs {mux[selector]}")
    return SignalRoute(key, src.name, dst.name, target, maps, send,
                       (fc.cycle_time_ms or 0) * 1_000_000, _ms(chk, item, "timeout_ms", key),
                       _ms(chk, item, "min_interval_ms", key), _ms(chk, item, "delay_ms", key),
                       e2e, tuple(sorted(mux.items())))


def _signal_map(chk: _Check, key: str, src: BusSpec, fc, target: str, ref: Any) -> SignalMap:
    if not isinstance(ref, str) or ref.count(".") != 1:
        raise chk.fail(key, f"expected \"MESSAGE.SIGNAL\", got {ref!r}")
    message, signal = ref.split(".")
    if message not in src.codec:
        raise chk.fail(key, f"unknown message {message!r} on bus {src.name!r}")
    sfc = src.codec[message]
    if signal not in {s.name for s in sfc.signals}:
        raise chk.fail(key, f"message {message} has no signal {signal!r}")
    if target not in {s.name for s in fc.signals}:
        raise chk.fail(key, f"message {fc.name} has no signal {target!r}")
    s_sig, t_sig = sfc.signal(signal), fc.signal(target)
    factor, offset = 1.0, 0.0
    if s_sig.unit and t_sig.unit and s_sig.unit != t_sig.unit:
        conv = UNIT_CONVERSIONS.get((s_sig.unit, t_sig.unit))
        if conv is None:
            raise chk.fail(key, f"unit {s_sig.unit!r} of {ref} cannot become {t_sig.unit!r}")
        factor, offset = conv
    s_choices, t_choices = sfc.choices.get(signal), fc.choices.get(target)
    if s_choices and t_choices:
        missing = sorted(set(s_choices.values()) - set(t_choices.values()))
        if missing:
            raise chk.fail(key, f"choices {missing} of {ref} are not choices of {target}")
    elif t_choices or s_choices:
        raise chk.fail(key, f"{ref} and {target}: choices map by name, only one has choices")
    else:  # ranges: a source range wholly outside the target's can never be carried
        lo, hi = sfc.ranges[signal]
        tlo, thi = fc.ranges[target]
        if lo is not None and hi is not None and tlo is not None and thi is not None:
            a, b = sorted((lo * factor + offset, hi * factor + offset))
            if b < tlo or a > thi:
                raise chk.fail(key, f"{ref}'s range [{a:g}, {b:g}] does not fit {target}'s "
                                    f"[{tlo:g}, {thi:g}]")
    return SignalMap(target, message, signal, factor, offset)


def _e2e(chk: _Check, item: dict, key: str, fc, maps: tuple[SignalMap, ...]) -> E2EProtection:
    spec = chk.table(item["e2e"], E2E, f"{key}.e2e.")
    if "profile" not in spec:
        raise chk.fail(f"{key}.e2e.profile", "required key missing")
    spec = {k: tuple(v) if k == "data_id_list" else v for k, v in spec.items()}
    try:
        prot = E2EProtection(**spec)
    except (E2EConfigError, TypeError) as exc:
        raise chk.fail(f"{key}.e2e", str(exc)) from None
    problem = prot.fits(fc.length)
    if problem is not None:
        raise chk.fail(f"{key}.e2e", f"does not fit {fc.name}: {problem}")
    header = set(range(prot.offset, prot.offset + prot.kind.header_bytes))
    for m in maps:
        if fc.signal_bytes[m.target] & header:
            raise chk.fail(f"{key}.e2e", f"{prot.profile}'s header (bytes {min(header)}.."
                                         f"{max(header)}) overlaps target signal {m.target}")
    return prot


def _deny(chk: _Check, item: Any, key: str, buses: dict[str, BusSpec]) -> DenyRule:
    chk.table(item, DENY, key + ".")
    src = _bus_ref(chk, buses, item, key, "from")
    ids = item.get("ids", [])
    if not ids or not all(isinstance(i, int) and 0 <= i <= 0x1FFFFFFF for i in ids):
        raise chk.fail(f"{key}.ids", f"expected CAN IDs 0..0x1FFFFFFF, got {ids}")
    return DenyRule(key, src.name, frozenset(ids))


__all__ = ["BusSpec", "DenyRule", "FrameRoute", "RoutingConfig", "SignalMap", "SignalRoute",
           "load_routing_config", "parse_routing_config"]
