"""Scenario files (TOML): load, validate, turn into a RunConfig plus pass criteria.

Every problem is one ScenarioError line naming the file, the key and the reason, e.g.
``scenarios/x.toml: key 'faults[1].start_s': 5 s is outside the run (0..3 s)``.
The format is documented in docs/scenarios.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from vecu import functions
from vecu.codec import DbcCodec, shared_codec
from vecu.config import ParamTree, RunConfig, apply_params, shortcut_sets, validate_tree
from vecu.ecu.sensor_monitor import DtcState, SensorMonitorConfig, SensorStatus
from vecu.errors import BadArgumentError, BadFileError, UserError
from vecu.estimators.registry import MANIFOLD_FILTERS, THROTTLE_ESTIMATORS
from vecu.faults import FaultInjector, ScheduledFault, parse_kind, parse_site
from vecu.fmu.binding import FmuBinding, load_binding
from vecu.gateway import route_faults
from vecu.gateway.routes import RoutingConfig
from vecu.gateway.routes_config import load_routing_config, parse_routing_config
from vecu.params import ParamError, flatten_toml
from vecu.plant.longitudinal import MANOEUVRES
from vecu.restbus.node import RestbusNode
from vecu.restbus.spec import RestbusConfig, build_plans
from vecu.tomlfile import read_toml
from vecu.uds.config import UdsStep
from vecu.uds.diag_faults.setting import DiagFaultSetting, setting_from_table
from vecu.xcp.config import XcpStep

# the diagnosed sensors of the ECU's functions (vecu.functions): short name -> its monitor's
# tree path, its frame, the function a run may leave out
MONITOR_PATHS = {short: sensor.monitor for short, (_, sensor) in functions.sensors().items()}
SENSORS = {short: sensor.message for short, (_, sensor) in functions.sensors().items()}
SENSOR_PART = {short: fn for short, (fn, _) in functions.sensors().items()
               if fn in functions.OPTIONAL}
# which part sends a message (a fault on a message nobody sends would do nothing): the
# messages the optional functions read
MESSAGE_PART = {inp.message: name for name in functions.OPTIONAL
                for inp in functions.spec(name).inputs.values()}
MAX_SERIES_S = 600.0  # longer runs keep no per-tick series (memory): no plots, no error criteria
NUMBER, INT, BOOL, STR = "a number", "an integer", "true or false", "a string"

TOP_KEYS = {"name": STR, "description": STR, "duration_s": NUMBER, "seed": INT,
            "plant": dict, "ecu": dict, "set": dict, "faults": list, "criteria": dict,
            "uds": list, "restbus": dict, "xcp": list, "gateway": (str, dict), "fmu": dict,
            "diag_faults": list}
PLANT_KEYS = {"noise_scale": NUMBER, **dict.fromkeys(functions.OPTIONAL, BOOL),
              "speed_manoeuvres": list}
ECU_KEYS = {"estimator": STR, "manifold_filter": STR, **dict.fromkeys(SENSORS, dict)}
FAULT_KEYS = {"target": STR, "kind": STR, "start_s": NUMBER, "end_s": NUMBER, "value": NUMBER}
MONITOR_KEYS = {f.name: {float: NUMBER, int: INT, bool: BOOL}[type(f.default)]
                for f in fields(SensorMonitorConfig) if f.name != "cycle_ms"}
GLOBAL_CRITERIA = {"no_nan": BOOL, "no_overruns": BOOL, "no_false_dtc": BOOL}
SENSOR_CRITERIA = {"detect_within_ms": NUMBER, "detected_as": list, "fallback_within_ms": NUMBER,
                   "max_error_after_fallback": NUMBER, "rms_error_after_fallback": NUMBER,
                   "dtc": STR, "fault_at_s": NUMBER, "not_detected": BOOL}
BUS_CRITERIA = {"dtc": STR}
RESTBUS_KEYS = {"databases": list, "nodes": list, "e2e": STR, "values": STR,
                "default_cycle_ms": NUMBER}
UDS_KEYS = {"at_s": NUMBER, "request": STR, "functional": BOOL, "key": BOOL, "expect": STR,
            "expect_nrc": INT, "expect_contains": STR, "expect_absent": STR, "expect_none": BOOL}
XCP_KEYS = {"at_s": NUMBER, "write": STR, "value": NUMBER, "read": STR, "expect": NUMBER,
            "tolerance": NUMBER, "expect_min": NUMBER, "expect_max": NUMBER, "expect_error": STR}


class ScenarioError(BadFileError):
    """A bad scenario file: ScenarioError(path, problem), the problem naming the key."""


@dataclass(frozen=True)
class SensorCriteria:
    sensor: str
    detect_within_ms: float | None = None
    detected_as: tuple[str, ...] | None = None
    fallback_within_ms: float | None = None
    max_error_after_fallback: float | None = None
    rms_error_after_fallback: float | None = None
    dtc: str | None = None
    fault_at_s: float | None = None
    not_detected: bool = False  # the sensor must never leave 'ok'


@dataclass(frozen=True)
class Criteria:
    no_nan: bool = True
    no_overruns: bool = True
    no_false_dtc: bool = True
    sensors: tuple[SensorCriteria, ...] = ()
    bus_dtc: str | None = None


@dataclass(frozen=True)
class Scenario:
    path: str
    name: str
    description: str
    config: RunConfig
    criteria: Criteria
    gateway: RoutingConfig | None = None       # [gateway]: routing between buses beside the run
    route_faults: tuple[ScheduledFault, ...] = ()  # [[faults]] on its routes ("routes[i]")


class _Checker:
    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, reason: str) -> ScenarioError:
        return ScenarioError(self.path, f"key '{key}': {reason}")

    def table(self, data: Any, schema: dict[str, Any], prefix: str) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise self.fail(prefix.rstrip("."), f"expected a table, got {_tname(data)}")
        for key, value in data.items():
            if key not in schema:
                raise self.fail(prefix + key, f"unknown key (known: {', '.join(schema)})")
            self.typed(value, schema[key], prefix + key)
        return data

    def typed(self, value: Any, want: Any, key: str) -> None:
        if want == (str, dict):  # a file's path or the file's tables inline
            if not isinstance(value, (str, dict)):
                raise self.fail(key, f"expected a path or a table, got {_tname(value)}")
            return
        ok = {NUMBER: isinstance(value, (int, float)) and not isinstance(value, bool),
              INT: isinstance(value, int) and not isinstance(value, bool),
              BOOL: isinstance(value, bool), STR: isinstance(value, str),
              dict: isinstance(value, dict), list: isinstance(value, list)}[want]
        if not ok:
            name = {dict: "a table", list: "an array"}.get(want, want)
            raise self.fail(key, f"expected {name}, got {_tname(value)}")
        if want == NUMBER and not math.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {value}")


def _tname(value: Any) -> str:
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            dict: "a table", list: "an array"}.get(type(value), type(value).__name__)


def load_scenario(path: str | Path, codec: DbcCodec | None = None) -> Scenario:
    """Read and validate one scenario file; raises ScenarioError (one line) on any problem."""
    path = str(path)
    chk = _Checker(path)
    data = read_toml(path, ScenarioError)
    chk.table(data, TOP_KEYS, "")
    if "duration_s" not in data:
        raise chk.fail("duration_s", "required key missing")
    duration = float(data["duration_s"])
    if not 1e-3 <= duration <= 24 * 3600:  # at least one 1 ms tick
        raise chk.fail("duration_s", f"must be in [0.001, 86400] s, got {duration}")
    seed = data.get("seed", 0)
    if seed < 0:
        raise chk.fail("seed", f"must be >= 0, got {seed}")
    plant = chk.table(data.get("plant", {}), PLANT_KEYS, "plant.")
    ecu = chk.table(data.get("ecu", {}), ECU_KEYS, "ecu.")
    parts = {name: plant.get(name, False) for name in functions.OPTIONAL}
    noise = float(plant.get("noise_scale", 1.0))
    if noise < 0:
        raise chk.fail("plant.noise_scale", f"must be >= 0, got {noise}")
    manoeuvres = plant.get("speed_manoeuvres")
    if manoeuvres is not None:
        bad = [m for m in manoeuvres if m not in MANOEUVRES]
        if not manoeuvres or bad:
            raise chk.fail("plant.speed_manoeuvres",
                           f"expected names from {', '.join(MANOEUVRES)}, got {manoeuvres}")
    estimator = ecu.get("estimator", "production")
    if estimator not in THROTTLE_ESTIMATORS:
        raise chk.fail("ecu.estimator", f"unknown estimator {estimator!r} "
                                        f"(known: {', '.join(THROTTLE_ESTIMATORS)})")
    filt = ecu.get("manifold_filter", "sdkf")
    if filt not in MANIFOLD_FILTERS:
        raise chk.fail("ecu.manifold_filter", f"expected one of {', '.join(MANIFOLD_FILTERS)}, "
                                              f"got {filt!r}")
    monitors = {}
    for sensor in SENSORS:
        over = chk.table(ecu.get(sensor, {}), MONITOR_KEYS, f"ecu.{sensor}.")
        for key, value in over.items():
            if key != "enabled" and value < 0:
                raise chk.fail(f"ecu.{sensor}.{key}", f"must be >= 0, got {value}")
        monitors[sensor] = over
    restbus = _restbus(chk, data.get("restbus"), seed)
    restbus_node = restbus_checker(restbus, chk) if restbus is not None else None
    gateway = _gateway(chk, data.get("gateway"))
    route_keys: set[str] = set()
    if gateway is not None:
        route_keys = {r.key for r in gateway.frame_routes} | {r.key for r in gateway.signal_routes}
    faults, disturbances, on_routes = _faults(
        chk, data.get("faults", []), duration, parts,
        codec if codec is not None else functions.function_codec(),  # with the plug-ins' messages
        restbus_node, route_keys)
    criteria = _criteria(chk, data.get("criteria", {}), duration, parts)
    uds_steps = _uds_steps(chk, data.get("uds", []), duration)
    diag_faults = _diag_faults(chk, data.get("diag_faults", []), duration)
    xcp_steps = _xcp_steps(chk, data.get("xcp", []), duration)
    # (scenario key, tree path, value): a value the tree refuses names the key it came from
    sets: list[tuple[str, str, Any]] = []
    for sensor, group in MONITOR_PATHS.items():
        sets += [(f"ecu.{sensor}.{key}", f"{group}.{key}", value)
                 for key, value in monitors[sensor].items()]
    for key, name, value in (("plant.noise_scale", "noise_scale", noise),
                             ("ecu.estimator", "estimator", estimator),
                             ("ecu.manifold_filter", "manifold_filter", filt)):
        sets += [(key, leaf, v) for leaf, v in shortcut_sets(**{name: value})]
    # [set]: any leaf of `vecu params`, last wins
    sets += [("set", leaf, value) for leaf, value in flatten_toml(data.get("set", {}))]
    fmu = _fmu(chk, data.get("fmu"), path)
    params = ParamTree() if fmu is None else RunConfig().with_fmu(fmu).params
    try:
        for key, leaf, value in sets:  # noqa: B007 - `key` names the culprit in the except below
            params = apply_params(params, [(leaf, value)])
        key = "set"
        validate_tree(params)
    except ParamError as exc:
        raise ScenarioError(path, f"key '{key}': {exc}") from None
    config = RunConfig(
        duration_s=duration, seed=seed, kill_tps_at_s=None, keep_series=duration <= MAX_SERIES_S,
        speed_manoeuvres=tuple(manoeuvres) if manoeuvres else None, faults=faults,
        params=params, uds_steps=uds_steps, xcp_steps=xcp_steps, restbus=restbus,
        restbus_disturbances=disturbances, fmu=fmu, diag_faults=diag_faults, **parts)
    return Scenario(path, data.get("name", Path(path).stem), data.get("description", ""),
                    config, criteria, gateway, on_routes)


def _gateway(chk: _Checker, data: Any) -> RoutingConfig | None:
    """[gateway]: a gateway config inline, or `gateway = "GATEWAY.toml"` (relative to the
    scenario file); the plant and ECU on its first bus (vecu.gateway.sim)."""
    if data is None:
        return None
    if isinstance(data, str):
        return load_routing_config(Path(chk.path).parent / data)
    routing = parse_routing_config(data, chk.path)
    if not routing.buses:
        raise chk.fail("gateway.buses", "expected [gateway.buses.NAME] tables")
    return routing


def _fmu(chk: _Checker, data: Any, path: str) -> FmuBinding | None:
    """[fmu]: file = the FMU (relative to the scenario), the map's [fmu] keys, and its
    [fmu.inputs], [fmu.outputs], [fmu.parameters] tables (docs/fmu.md)."""
    if data is None:
        return None
    if not isinstance(data.get("file"), str):
        raise chk.fail("fmu.file", "expected the FMU's path (relative to the scenario)")
    tables = ("inputs", "outputs", "parameters")
    table = {"fmu": {k: v for k, v in data.items() if k not in (*tables, "file")},
             **{t: data[t] for t in tables if t in data}}
    return load_binding(str(Path(path).parent / data["file"]), path, table)


def _restbus(chk: _Checker, data: Any, seed: int) -> RestbusConfig | None:
    """[restbus]: the user's databases (paths relative to the scenario file) and options."""
    if data is None:
        return None
    chk.table(data, RESTBUS_KEYS, "restbus.")
    dbs = data.get("databases")
    if not dbs or not all(isinstance(d, str) for d in dbs):
        raise chk.fail("restbus.databases", "expected an array of DBC / ARXML paths")
    base = Path(chk.path).parent

    def here(p: str | None) -> str | None:
        return None if p is None else str(p if Path(p).is_absolute() else base / p)
    nodes = data.get("nodes", [])
    if not all(isinstance(n, str) for n in nodes):
        raise chk.fail("restbus.nodes", "expected an array of node names")
    cycle = data.get("default_cycle_ms")
    if cycle is not None and not 0.1 <= cycle <= 3_600_000:
        raise chk.fail("restbus.default_cycle_ms", f"must be in [0.1, 3600000], got {cycle}")
    return RestbusConfig(tuple(str(here(d)) for d in dbs), tuple(nodes), here(data.get("e2e")),
                         here(data.get("values")), cycle, seed)


def companion_files(path: str | Path) -> list[str]:
    """The files scenario `path` names by a relative path ([restbus] databases, e2e, values), as
    written: what a copy of the scenario takes along so that it runs as is."""
    restbus = read_toml(path, ScenarioError).get("restbus") or {}
    named = [*restbus.get("databases", []), restbus.get("e2e"), restbus.get("values")]
    return [p for p in named if isinstance(p, str) and not Path(p).is_absolute()]


def restbus_checker(cfg: RestbusConfig, chk: _Checker) -> RestbusNode:
    """The restbus of cfg, built (every database and file check) but not scheduled: it checks
    the [[faults]] aimed at it."""
    try:
        plans, _, _ = build_plans(replace(cfg, exclude=frozenset(shared_codec().by_id)))
    except UserError as exc:
        raise chk.fail("restbus", str(exc)) from None
    return RestbusNode(plans, lambda msg: True, np.random.default_rng(0))


def _faults(chk: _Checker, items: list, duration: float, parts: dict[str, bool],
            codec: DbcCodec | None, restbus: RestbusNode | None = None,
            route_keys: set[str] | frozenset[str] = frozenset(),
            ) -> tuple[tuple[ScheduledFault, ...], ...]:
    """[[faults]]: on vecu's own sensors and frames (the injector), on a message of the
    restbus (a restbus disturbance, vecu.restbus.disturb), or on a gateway route (its key,
    vecu.gateway.route_faults): (faults, disturbances, route faults)."""
    injector = FaultInjector(np.random.default_rng(0), codec)
    out = []
    disturbances = []
    on_routes = []
    for i, item in enumerate(items):
        pre = f"faults[{i}]."
        chk.table(item, FAULT_KEYS, pre)
        for req in ("target", "kind", "start_s"):
            if req not in item:
                raise chk.fail(pre + req, "required key missing")
        start, end = float(item["start_s"]), item.get("end_s")
        if not 0 <= start < duration:
            raise chk.fail(pre + "start_s", f"{start:g} s is outside the run (0..{duration:g} s)")
        if end is not None and not start < end:
            raise chk.fail(pre + "end_s", f"{end:g} s is not after start_s = {start:g} s")
        if item["target"] in route_keys:
            try:
                route_faults.check(item["kind"], item.get("value"))
            except UserError as exc:
                raise chk.fail(pre + "kind", str(exc)) from None
            on_routes.append(ScheduledFault(item["target"], item["kind"], start,
                                            None if end is None else float(end),
                                            item.get("value")))
            continue
        if restbus is not None and _on_restbus(restbus, item["target"]):
            try:
                restbus.check(item["target"], item["kind"], item.get("value"))
            except ValueError as exc:
                raise chk.fail(pre + "kind", str(exc)) from None
            disturbances.append(ScheduledFault(
                item["target"], item["kind"], start, None if end is None else float(end),
                item.get("value")))
            continue
        try:
            kind = parse_kind(item["kind"])
        except ValueError as exc:
            raise chk.fail(pre + "kind", str(exc)) from None
        if kind == 0:
            raise chk.fail(pre + "kind", "'clear' is not a fault (use end_s)")
        try:
            site = injector.check(item["target"], kind, item.get("value"))
        except ValueError as exc:
            key = "value" if "must be" in str(exc) or "G must" in str(exc) else "target"
            raise chk.fail(pre + key, str(exc)) from None
        part = MESSAGE_PART.get(parse_site(site).message)
        if part is not None and not parts[part]:
            raise chk.fail(pre + "target", f"{site.message} is sent by the {part} part: set "
                                           f"plant.{part} = true")
        out.append(ScheduledFault(item["target"], item["kind"], start,
                                  None if end is None else float(end), item.get("value")))
    return tuple(out), tuple(disturbances), tuple(on_routes)


def _on_restbus(node: RestbusNode, target: str) -> bool:
    try:
        node.resolve(target)
    except ValueError:
        return False
    return True


def parse_criteria(path: str, data: Any) -> Criteria:
    """A `[criteria]` table on its own (e.g. a fleet replay's --criteria file): the same keys and
    checks as a scenario's, every part present, no run length to hold fault times to."""
    return _criteria(_Checker(path), data, math.inf, dict.fromkeys(SENSOR_PART.values(), True))


def _criteria(chk: _Checker, data: dict, duration: float, parts: dict[str, bool]) -> Criteria:
    schema = {**GLOBAL_CRITERIA, **dict.fromkeys(SENSORS, dict), "bus": dict}
    chk.table(data, schema, "criteria.")
    dtc_names = [s.name.lower() for s in DtcState]
    status_names = [s.name.lower() for s in SensorStatus if s != SensorStatus.OK]
    sensors = []
    for sensor in SENSORS:
        if sensor not in data:
            continue
        pre = f"criteria.{sensor}."
        c = chk.table(data[sensor], SENSOR_CRITERIA, pre)
        part = SENSOR_PART.get(sensor)
        if part is not None and not parts[part]:
            raise chk.fail(pre.rstrip("."), f"needs the {part} part: set plant.{part} = true")
        if "dtc" in c and c["dtc"] not in dtc_names:
            raise chk.fail(pre + "dtc", f"expected one of {', '.join(dtc_names)}, got {c['dtc']!r}")
        if "detected_as" in c and (not c["detected_as"]
                                   or any(s not in status_names for s in c["detected_as"])):
            raise chk.fail(pre + "detected_as",
                           f"expected names from {', '.join(status_names)}, got {c['detected_as']}")
        if "fault_at_s" in c and not 0 <= c["fault_at_s"] < duration:
            raise chk.fail(pre + "fault_at_s",
                           f"{c['fault_at_s']:g} s is outside the run (0..{duration:g} s)")
        for key in ("detect_within_ms", "fallback_within_ms", "max_error_after_fallback",
                    "rms_error_after_fallback"):
            if key in c and c[key] < 0:
                raise chk.fail(pre + key, f"must be >= 0, got {c[key]}")
        sensors.append(SensorCriteria(sensor, **{
            **c, **({"detected_as": tuple(c["detected_as"])} if "detected_as" in c else {})}))
    bus = chk.table(data.get("bus", {}), BUS_CRITERIA, "criteria.bus.")
    if "dtc" in bus and bus["dtc"] not in dtc_names:
        raise chk.fail("criteria.bus.dtc", f"expected one of {', '.join(dtc_names)}")
    return Criteria(no_nan=data.get("no_nan", True), no_overruns=data.get("no_overruns", True),
                    no_false_dtc=data.get("no_false_dtc", True), sensors=tuple(sensors),
                    bus_dtc=bus.get("dtc"))


def _hex(chk: _Checker, key: str, text: str) -> bytes:
    try:
        data = bytes.fromhex(text.replace("0x", "").replace(",", " "))
    except ValueError:
        raise chk.fail(key, f"expected hex bytes like '22 F1 90', got {text!r}") from None
    return data


def _uds_steps(chk: _Checker, items: list, duration: float) -> tuple[UdsStep, ...]:
    """[[uds]]: requests a tester sends at at_s, and what each response must be."""
    out = []
    for i, item in enumerate(items):
        pre = f"uds[{i}]."
        chk.table(item, UDS_KEYS, pre)
        for req in ("at_s", "request"):
            if req not in item:
                raise chk.fail(pre + req, "required key missing")
        at = float(item["at_s"])
        if not 0 <= at < duration:
            raise chk.fail(pre + "at_s", f"{at:g} s is outside the run (0..{duration:g} s)")
        request = _hex(chk, pre + "request", item["request"])
        if not 1 <= len(request) <= 4095:
            raise chk.fail(pre + "request", f"expected 1 to 4095 bytes, got {len(request)}")
        if item.get("functional") and len(request) > 7:
            raise chk.fail(pre + "request", "a functional request fits one frame (<= 7 bytes)")
        nrc = item.get("expect_nrc")
        if nrc is not None and not 0 < nrc <= 0xFF:
            raise chk.fail(pre + "expect_nrc", f"expected a code 1..255, got {nrc}")
        out.append(UdsStep(
            at, request, functional=item.get("functional", False), key=item.get("key", False),
            expect_nrc=nrc, expect_none=item.get("expect_none", False),
            **{k: _hex(chk, pre + k, item[k]) for k in
               ("expect", "expect_contains", "expect_absent") if k in item}))
    return tuple(out)


def _diag_faults(chk: _Checker, items: list, duration: float) -> tuple[DiagFaultSetting, ...]:
    """[[diag_faults]]: name, value, at_s, until_s or request (vecu conformance list)."""
    out = []
    for i, item in enumerate(items):
        pre = f"diag_faults[{i}]"
        if not isinstance(item, dict):
            raise chk.fail(pre, "expected a table")
        try:
            s = setting_from_table(item, pre)
        except (BadArgumentError, TypeError, ValueError) as exc:
            raise chk.fail(pre, str(exc)) from None
        if s.start_s >= duration:
            raise chk.fail(pre + ".at_s", f"{s.start_s:g} s is outside the run (0..{duration:g} s)")
        out.append(s)
    return tuple(out)


def _xcp_steps(chk: _Checker, items: list, duration: float) -> tuple[XcpStep, ...]:
    """[[xcp]]: a master's writes of characteristics and reads at at_s, and what must come
    (names as in `vecu a2l`; checked against the A2L when the run starts)."""
    out = []
    for i, item in enumerate(items):
        pre = f"xcp[{i}]."
        chk.table(item, XCP_KEYS, pre)
        if "at_s" not in item:
            raise chk.fail(pre + "at_s", "required key missing")
        at = float(item["at_s"])
        if not 0 <= at < duration:
            raise chk.fail(pre + "at_s", f"{at:g} s is outside the run (0..{duration:g} s)")
        if "write" not in item and "read" not in item:
            raise chk.fail(pre + "write", "a step writes a characteristic or reads a value")
        if ("write" in item) != ("value" in item):
            raise chk.fail(pre + "value", "'write' and 'value' go together")
        if "expect_error" in item and "write" not in item:
            raise chk.fail(pre + "expect_error", "an expected error is the write's")
        if "expect_error" in item and not item["expect_error"].startswith("ERR_"):
            raise chk.fail(pre + "expect_error",
                           f"expected an XCP error name like ERR_OUT_OF_RANGE, got "
                           f"{item['expect_error']!r}")
        kw: dict[str, Any] = {k: (float(v) if isinstance(v, (int, float))
                                  and not isinstance(v, bool) else v)
                              for k, v in item.items() if k != "at_s"}
        out.append(XcpStep(at, **kw))
    return tuple(out)
