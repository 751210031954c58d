"""Bring your own DBC: a TOML signal map says which message.signal of the user's database feeds
each ECU input, with unit conversion; the result is the ECU's receive table (ecu.node.Route).

    [speed]
    wheel_speed = { signal = "WheelSpeeds.WheelSpeedFL", unit = "km/h" }
    long_accel  = { signal = "IMU.AccelX", unit = "g" }

Unit: the map's `unit`, else the signal's unit in the DBC; converted to the ECU's unit (table
function_inputs()). `scale` / `offset` (applied first: x * scale + offset) cover anything else. A function
with a required input unmapped is disabled, with the reason in the summary.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from vecu import functions
from vecu.codec import DbcCodec
from vecu.ecu.node import EcuFunction, Route, Subscription
from vecu.errors import BadFileError
from vecu.functions.base import EcuInput
from vecu.tomlfile import read_toml


class SignalMapError(BadFileError):
    """A bad signal map: SignalMapError(path, problem), the problem naming the key."""


def function_inputs() -> dict[str, Mapping[str, EcuInput]]:
    """function -> input name -> where it lands in vecu's own messages (the registry's
    functions, vecu.functions: each spec's `inputs`)."""
    return {spec.name: spec.inputs for spec in functions.specs() if spec.inputs}


# unit -> (family, factor, offset): value in the family's base unit = x * factor + offset
_UNITS: dict[str, tuple[str, float, float]] = {
    "km/h": ("speed", 1.0, 0.0), "kph": ("speed", 1.0, 0.0), "m/s": ("speed", 3.6, 0.0),
    "mph": ("speed", 1.609344, 0.0), "kn": ("speed", 1.852, 0.0),
    "m/s^2": ("accel", 1.0, 0.0), "m/s2": ("accel", 1.0, 0.0), "m/s²": ("accel", 1.0, 0.0),
    "g": ("accel", 9.80665, 0.0),
    "deg": ("angle", 1.0, 0.0), "°": ("angle", 1.0, 0.0), "rad": ("angle", 180.0 / math.pi, 0.0),
    "deg/s": ("rate", 1.0, 0.0), "°/s": ("rate", 1.0, 0.0),
    "rad/s": ("rate", 180.0 / math.pi, 0.0),
    "rpm": ("rotation", 1.0, 0.0), "1/min": ("rotation", 1.0, 0.0),
    "kPa": ("pressure", 1.0, 0.0), "Pa": ("pressure", 1e-3, 0.0), "hPa": ("pressure", 0.1, 0.0),
    "mbar": ("pressure", 0.1, 0.0), "bar": ("pressure", 100.0, 0.0),
    "psi": ("pressure", 6.894757, 0.0),
    "degC": ("temperature", 1.0, 0.0), "°C": ("temperature", 1.0, 0.0), "C": ("temperature", 1.0, 0.0),
    "K": ("temperature", 1.0, -273.15), "degF": ("temperature", 5.0 / 9.0, -160.0 / 9.0),
    "V": ("voltage", 1.0, 0.0), "mV": ("voltage", 1e-3, 0.0),
    "W": ("power", 1.0, 0.0), "kW": ("power", 1e3, 0.0),
}
_ALIASES = {"km/hr": "km/h", "kmh": "km/h", "m/sec^2": "m/s^2", "m/s/s": "m/s^2",
            "degree": "deg", "degrees": "deg", "deg/sec": "deg/s", "degrees/s": "deg/s",
            "degree/s": "deg/s", "dps": "deg/s", "rev/min": "rpm", "kpa": "kPa",
            "celsius": "degC", "°c": "degC", "volt": "V", "volts": "V", "watt": "W"}


def unit_conversion(src: str, dst: str) -> tuple[float, float]:
    """(factor, offset) with value_dst = value_src * factor + offset; ValueError if unknown or
    of another quantity ('rad/s' is a rate for angles, rpm-like for engine speed)."""
    src_n, dst_n = _ALIASES.get(src, src), _ALIASES.get(dst, dst)
    if src_n == dst_n:
        return 1.0, 0.0
    if dst_n == "rpm" and src_n == "rad/s":
        return 60.0 / (2.0 * math.pi), 0.0
    if src_n not in _UNITS:
        raise ValueError(f"unknown unit {src!r} (known: {', '.join(sorted(_UNITS))})")
    fam_s, f_s, o_s = _UNITS[src_n]
    fam_d, f_d, o_d = _UNITS[dst_n]
    if fam_s != fam_d:
        raise ValueError(f"cannot convert {src!r} ({fam_s}) to {dst!r} ({fam_d})")
    return f_s / f_d, (o_s - o_d) / f_d


@dataclass(frozen=True)
class MappedInput:
    """One mapped input: foreign message.signal -> vecu message.signal, y = x * factor + offset."""

    function: str
    name: str
    source_message: str
    source_signal: str
    target: EcuInput
    factor: float
    offset: float
    source_unit: str


@dataclass(frozen=True)
class SignalMap:
    path: str
    inputs: tuple[MappedInput, ...]
    disabled: dict[str, str] = field(default_factory=dict)  # function -> reason
    notes: tuple[str, ...] = ()  # optional inputs left out, and what that means


def load_signal_map(path: str | Path, db: DbcCodec) -> SignalMap:
    """Read and check a TOML map against the trace's database; errors name file and key."""
    path = str(path)
    return build_signal_map(read_toml(path, SignalMapError), db, path)


def build_signal_map(doc: dict, db: DbcCodec, path: str = "<map>") -> SignalMap:
    mapped: list[MappedInput] = []
    INPUTS = function_inputs()
    for fn_name, table in doc.items():
        if fn_name not in INPUTS:
            raise SignalMapError(path, f"[{fn_name}]: unknown function "
                                 f"(known: {', '.join(INPUTS)})")
        if not isinstance(table, dict):
            raise SignalMapError(path, f"{fn_name}: must be a table of inputs")
        for name, spec in table.items():
            key = f"{fn_name}.{name}"
            if name not in INPUTS[fn_name]:
                raise SignalMapError(path, f"{key}: unknown input "
                                     f"(known: {', '.join(INPUTS[fn_name])})")
            mapped.append(_mapped_input(path, key, fn_name, name, spec, db))
    return _with_coverage(path, mapped)


def identity_map(db: DbcCodec) -> SignalMap:
    """vecu's own messages, where the trace's database has them (no --map needed)."""
    mapped = []
    for fn_name, table in function_inputs().items():
        for name, target in table.items():
            if target.message in db and target.signal in db[target.message].ranges:
                mapped.append(MappedInput(fn_name, name, target.message, target.signal, target,
                                          1.0, 0.0, target.unit))
    return _with_coverage("<vecu DBC>", mapped)


def _mapped_input(path: str, key: str, fn_name: str, name: str, spec: object,
                  db: DbcCodec) -> MappedInput:
    if isinstance(spec, str):
        spec = {"signal": spec}
    if not isinstance(spec, dict):
        raise SignalMapError(path, f"{key}: expected a table like "
                             f'{{ signal = "Message.Signal", unit = "km/h" }}')
    unknown = set(spec) - {"signal", "unit", "scale", "offset"}
    if unknown:
        raise SignalMapError(path, f"{key}: unknown key {min(unknown)!r} "
                             f"(allowed: signal, unit, scale, offset)")
    ref = spec.get("signal")
    if not isinstance(ref, str) or ref.count(".") != 1:
        raise SignalMapError(path, f"{key}.signal: expected \"Message.Signal\", got {ref!r}")
    msg_name, sig_name = ref.split(".")
    if msg_name not in db:
        raise SignalMapError(path, f"{key}.signal: no message {msg_name!r} in "
                             f"{', '.join(Path(p).name for p in db.paths)}")
    fc = db[msg_name]
    if sig_name not in fc.ranges:
        raise SignalMapError(path, f"{key}.signal: message {msg_name} has no signal "
                             f"{sig_name!r}")
    target = function_inputs()[fn_name][name]
    dbc_unit = fc.signal(sig_name).unit
    unit = spec.get("unit", dbc_unit or target.unit)
    for opt in ("scale", "offset"):
        if opt in spec and (isinstance(spec[opt], bool)
                            or not isinstance(spec[opt], (int, float))
                            or not math.isfinite(spec[opt])):
            raise SignalMapError(path, f"{key}.{opt}: expected a finite number")
    if not isinstance(unit, str):
        raise SignalMapError(path, f"{key}.unit: expected a string")
    try:
        factor, offset = unit_conversion(unit, target.unit)
    except ValueError as exc:
        raise SignalMapError(path, f"{key}.unit: {exc}") from exc
    scale, pre = float(spec.get("scale", 1.0)), float(spec.get("offset", 0.0))
    return MappedInput(fn_name, name, msg_name, sig_name, target, scale * factor,
                       pre * factor + offset, unit)


def _with_coverage(path: str, mapped: list[MappedInput]) -> SignalMap:
    have = {(m.function, m.name) for m in mapped}
    disabled, notes = {}, []
    for fn_name, table in function_inputs().items():
        missing = [n for n, inp in table.items() if inp.required and (fn_name, n) not in have]
        if missing:
            disabled[fn_name] = (f"{fn_name} estimator disabled: no mapping for "
                                 f"{', '.join(f'{fn_name}.{n}' for n in missing)}")
            continue
        for n, inp in table.items():
            if not inp.required and (fn_name, n) not in have:
                notes.append(f"{fn_name}.{n} not mapped: the {fn_name} function reports that "
                             f"sensor as timed out and broadcasts its estimate")
    return SignalMap(path, tuple(mapped), disabled, tuple(notes))


# ------------------------------------------------------------------ receive table
class _Assembler:
    """Collects mapped values of one vecu message and delivers it, complete, to the function
    each time its trigger message (the source of its first mapped input) arrives."""

    def __init__(self, target_message: str, deliver: Callable[[dict[str, float], int], None],
                 defaults: dict[str, float], counter_signals: tuple[str, ...]) -> None:
        self.target = target_message
        self.deliver = deliver
        self.values = dict(defaults)
        self.missing: set[str] = set()  # mapped signals not received yet
        self.counter_signals = counter_signals
        self.count = 0
        # counters taken from another message's (ENG_Intake carries its ENG_Event's counter)
        self.counter_of: _Assembler | None = None

    def deliver_now(self, t_ns: int) -> None:
        if self.missing:
            return
        # synthesised counters: one per delivered message, or the last one of counter_of
        count = self.count if self.counter_of is None else self.counter_of.count - 1
        for name in self.counter_signals:
            self.values[name] = float(count & 0xFF)
        self.count += 1
        self.deliver(dict(self.values), t_ns)


def mapped_routes(smap: SignalMap, db: DbcCodec, ecu_codec: DbcCodec,
                  functions: dict[str, EcuFunction]) -> dict[tuple[int, bool], Route]:
    """The ECU's receive table for a mapped trace. Mapped messages have no vecu E2E: their
    CRC / alive counter checks do not apply, counters are synthesised per message."""
    subs: dict[str, tuple[Subscription, EcuFunction]] = {}
    for fn in functions.values():
        for sub in fn.subscriptions():
            subs[sub.message] = (sub, fn)
    assemblers: dict[str, _Assembler] = {}
    per_source: dict[str, list[tuple[MappedInput, _Assembler]]] = {}
    for m in smap.inputs:
        if m.function not in functions or m.target.message not in subs:
            continue
        sub, _fn = subs[m.target.message]
        asm = assemblers.get(m.target.message)
        if asm is None:
            target_fc = ecu_codec[m.target.message]
            defaults = {s: 0.0 for s in target_fc.ranges}
            counters = tuple(s for s in target_fc.ranges if s.endswith("Counter"))
            asm = _Assembler(m.target.message, sub.on_values, defaults, counters)
            assemblers[m.target.message] = asm
        asm.missing.add(m.target.signal)  # delivered once every mapped signal has been seen
        per_source.setdefault(m.source_message, []).append((m, asm))
    # the ENG_Intake counter must match the event it belongs to: share the event's count
    if "ENG_Intake" in assemblers and "ENG_Event" in assemblers:
        assemblers["ENG_Intake"].counter_of = assemblers["ENG_Event"]
    triggers = {}
    for m in smap.inputs:
        asm = assemblers.get(m.target.message)
        if asm is not None and asm.target not in triggers:
            triggers[asm.target] = m.source_message
    routes = {}
    for source, entries in per_source.items():
        fc = db[source]
        fire = [a for a in {id(a): a for _, a in entries}.values() if triggers[a.target] == source]
        convs = [(m.source_signal, m.target.signal, m.factor, m.offset, a) for m, a in entries]
        fed = tuple({id(f): f for f in (subs[a.target][1] for _, a in entries)}.values())
        # a third-party frame is not rejected for a signal the ECU does not use
        route_codec = fc.checking_only(m.source_signal for m, _ in entries)
        routes[(fc.frame_id, fc.is_extended)] = Route(
            route_codec, Subscription(source, _route_callback(convs, fire)), None, fed)
    return routes


def _route_callback(convs: list[tuple[str, str, float, float, _Assembler]],
                    fire: list[_Assembler]) -> Callable[[dict[str, float], int], None]:
    def on_values(values: dict[str, float], t_ns: int) -> None:
        for src, dst, factor, offset, asm in convs:
            v = values.get(src)  # absent when another multiplexer page is in this frame
            if v is not None:
                asm.values[dst] = v * factor + offset
                if asm.missing:
                    asm.missing.discard(dst)
        for asm in fire:
            asm.deliver_now(t_ns)
    return on_values

