"""Run configuration and the parameter tree, shared by the simulated run, live processes, replay,
scenarios and campaigns.

The tree has two halves that default to equal values: `plant.*`, the simulated car (the truth),
and `ecu.*`, what the ECU believes (its calibration). A robustness study sets them apart, e.g.
`--set plant.manifold.engine.v_im_dm3=5.25` leaves the ECU on the nominal engine. The mechanics
(dotted paths, units, sources, parsing) are vecu.params; this module is the harness floor, so it
may name the plant's and the ECU's configuration classes (docs/architecture.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields, make_dataclass, replace
from typing import TYPE_CHECKING, Any

from vecu import params as ptree
from vecu.bus import RxBudget
from vecu.ecu.manifold_function import ManifoldFunctionConfig
from vecu.ecu.speed_function import SpeedFunctionConfig
from vecu.ecu.steering_function import SteeringFunctionConfig
from vecu.ecu.throttle_function import ThrottleFunctionConfig
from vecu.errors import ConfigError
from vecu.estimators.registry import MANIFOLD_FILTERS, THROTTLE_ESTIMATORS
from vecu.fault_kinds import check_value
from vecu.faults import FaultKind, ScheduledFault, parse_kind
from vecu.fmu.binding import FmuBinding, NoFmu, parameter_tree
from vecu.instances import ECU_NODE, MAX_INSTANCE, check_distinct, uds_ids, xcp_ids
from vecu.models.lateral import VehicleParams
from vecu.models.sensors import TpsCalibration
from vecu.plant.driveline import Driveline
from vecu.plant.input_file import load_input_file
from vecu.plant.lateral import LateralSensors
from vecu.plant.longitudinal import AccelSensorConfig, WheelSensorConfig
from vecu.plant.manifold import ManifoldPlantConfig
from vecu.plant.throttle import InputConfig, ThrottlePlantConfig
from vecu.restbus.spec import RestbusConfig
from vecu.uds.config import UdsConfig, UdsStep
from vecu.xcp.config import XcpConfig, XcpStep, check_xcp

if TYPE_CHECKING:
    from vecu.codec import DbcCodec


@dataclass(frozen=True)
class PlantSensors:
    """The simulated sensors' transfer laws and noise."""

    tps: TpsCalibration = field(default_factory=TpsCalibration)
    wheel: WheelSensorConfig = field(default_factory=WheelSensorConfig)
    accel: AccelSensorConfig = field(default_factory=AccelSensorConfig)
    lateral: LateralSensors = field(default_factory=LateralSensors)


@dataclass(frozen=True)
class PlantParams:
    """The simulated car: throttle body and its excitation, vehicle, engine, sensors, driveline."""

    throttle: ThrottlePlantConfig = field(default_factory=ThrottlePlantConfig)
    input: InputConfig = field(default_factory=InputConfig)
    lateral: VehicleParams = field(default_factory=VehicleParams)
    manifold: ManifoldPlantConfig = field(default_factory=ManifoldPlantConfig)
    sensors: PlantSensors = field(default_factory=PlantSensors)
    driveline: Driveline = field(default_factory=Driveline)  # gears: engine speed from speed


@dataclass(frozen=True)
class EcuParams:
    """What the ECU believes and how it decides: one configuration per ECU function."""

    throttle: ThrottleFunctionConfig = field(default_factory=ThrottleFunctionConfig)
    speed: SpeedFunctionConfig = field(default_factory=SpeedFunctionConfig)
    steering: SteeringFunctionConfig = field(default_factory=SteeringFunctionConfig)
    manifold: ManifoldFunctionConfig = field(default_factory=ManifoldFunctionConfig)
    # which of several ECUs on one bus: moves the UDS / XCP IDs and the ECU's frames
    # (vecu.instances, docs/live.md 'Several ECUs on one bus'); 0: vecu's own IDs
    instance: int = field(default=0, metadata={"bounds": (0, MAX_INSTANCE)})
    uds: UdsConfig = field(default_factory=UdsConfig)  # diagnostics server (docs/uds.md)
    xcp: XcpConfig = field(default_factory=XcpConfig)  # measurement and calibration (docs/xcp.md)
    rx: RxBudget = field(default_factory=RxBudget)  # receive work per 1 ms tick (docs/live.md)
    # an FMU's parameters, ecu.fmu.<instance>.<variable> (RunConfig.with_fmu; docs/fmu.md)
    fmu: Any = field(default_factory=NoFmu)


_EXTENDED: dict[tuple[tuple[str, Callable[[], Any]], ...], type] = {}


def ecu_params() -> EcuParams:
    """The default `ecu` half: EcuParams, with a field per plug-in subtree when there are any
    (vecu.params.ecu_subtrees; a frozen subclass made once per set of subtrees, so that equal
    trees compare equal)."""
    extra = ptree.ecu_subtrees()
    if not extra:
        return EcuParams()
    cls = _EXTENDED.get(extra)
    if cls is None:
        cls = _EXTENDED[extra] = make_dataclass(
            "EcuParamsWithPlugins", [(name, Any, field(default_factory=factory))
                                     for name, factory in extra],
            bases=(EcuParams,), frozen=True, namespace={"__reduce__": _reduce_ecu})
    return cls()


def _reduce_ecu(ecu: EcuParams) -> tuple[Any, tuple[dict[str, Any]]]:
    """Pickle an extended `ecu` half by value: rebuilt in the receiving process (a campaign's
    or a scenario's worker) from its own plug-ins, which must be the same."""
    return _restore_ecu, ({f.name: getattr(ecu, f.name) for f in fields(ecu)},)


def _restore_ecu(values: dict[str, Any]) -> EcuParams:
    return replace(ecu_params(), **values)


@dataclass(frozen=True)
class ParamTree:
    """The whole parameter tree: `plant.*` (the truth) and `ecu.*` (the calibration; plug-in
    functions' subtrees included, ecu_params)."""

    plant: PlantParams = field(default_factory=PlantParams)
    ecu: EcuParams = field(default_factory=ecu_params)

    def set(self, sets: object) -> ParamTree:
        """A new tree with (path, value) pairs or a {path: value} mapping applied, checked."""
        tree = apply_params(self, sets)  # type: ignore[arg-type]  # pairs or a mapping; apply_sets checks each
        validate_tree(tree)
        return tree


def apply_params(tree: ParamTree, sets: Mapping[str, object] | Iterable[tuple[str, object]]
                 ) -> ParamTree:
    """ptree.apply_sets, then the ECU instance rule (vecu.instances): a UDS / XCP ID that these
    sets do not name and that still has the old instance's value follows `ecu.instance`."""
    pairs = list(sets.items()) if isinstance(sets, Mapping) else list(sets)
    new = ptree.apply_sets(tree, pairs)
    old_n, new_n = tree.ecu.instance, new.ecu.instance
    if old_n == new_n:
        return new
    named = {path for path, _ in pairs}
    moved = [(f"ecu.{group}.{leaf}", value)
             for group, rule in (("uds", uds_ids), ("xcp", xcp_ids))
             for leaf, value in rule(new_n).items()
             if f"ecu.{group}.{leaf}" not in named
             and ptree.get(new, f"ecu.{group}.{leaf}") == rule(old_n)[leaf]]
    return ptree.apply_sets(new, moved)


def check_ecu_ids(ecu: EcuParams, codec: DbcCodec | None = None) -> None:
    """The ECU's diagnostic IDs and its own frames' IDs on its instance all differ (ParamError
    naming the two that share one). codec: the one the ECU sends with (default vecu's own DBCs
    on ecu.instance; assembly.build_functions checks again with the plug-ins' DBCs)."""
    from vecu.codec import shared_codec

    ids = {}
    if ecu.uds.enabled:
        ids.update({f"ecu.uds.{leaf}": getattr(ecu.uds, leaf) for leaf in uds_ids(0)})
    if ecu.xcp.enabled:
        ids.update({f"ecu.xcp.{leaf}": getattr(ecu.xcp, leaf) for leaf in xcp_ids(0)})
    try:
        if codec is None:
            codec = shared_codec(ecu.instance)
        ids.update({f"frame {codec.by_id[key].name}": key[0]
                    for key in sorted(codec.sent_by(ECU_NODE))})
        check_distinct(ids)
    except ConfigError as exc:
        raise ptree.ParamError(f"the ECU's CAN IDs (ecu.instance = {ecu.instance}): {exc}") from None


# Command-line shortcuts: one flag that sets several leaves (both halves of the tree agree).
SHORTCUTS: dict[str, tuple[str, ...]] = {
    "noise_scale": ("plant.throttle.noise_scale", "ecu.throttle.noise_scale"),
    "estimator": ("ecu.throttle.estimator",),
    "manifold_filter": ("ecu.manifold.filter",),
}


def shortcut_sets(**values: object) -> list[tuple[str, object]]:
    """(path, value) pairs for the shortcut options given (None: not given)."""
    return [(path, v) for name, v in values.items() if v is not None for path in SHORTCUTS[name]]


def validate_tree(tree: ParamTree) -> None:
    """Checks beyond each leaf's type: names from their lists, scales that cannot be negative."""
    for path in ("plant.throttle.noise_scale", "ecu.throttle.noise_scale",
                 "plant.manifold.noise_scale"):
        if ptree.get(tree, path) < 0:
            raise ptree.ParamError(f"parameter '{path}' must be >= 0, got {ptree.get(tree, path)}")
    name = tree.ecu.throttle.estimator
    if name not in THROTTLE_ESTIMATORS:
        raise ptree.ParamError(f"parameter 'ecu.throttle.estimator': unknown estimator {name!r} "
                               f"(known: {', '.join(THROTTLE_ESTIMATORS)})")
    if tree.ecu.manifold.filter not in MANIFOLD_FILTERS:
        raise ptree.ParamError(f"parameter 'ecu.manifold.filter': expected one of "
                               f"{', '.join(MANIFOLD_FILTERS)}, got {tree.ecu.manifold.filter!r}")
    uds = tree.ecu.uds
    if len(uds.vin) != 17 or not uds.vin.isascii() or not uds.vin.isprintable():
        raise ptree.ParamError(f"parameter 'ecu.uds.vin': expected 17 printable ASCII "
                               f"characters, got {uds.vin!r}")
    if not 1 <= len(uds.serial) <= 32 or not uds.serial.isascii() or not uds.serial.isprintable():
        raise ptree.ParamError(f"parameter 'ecu.uds.serial': expected 1 to 32 printable ASCII "
                               f"characters, got {uds.serial!r}")
    ids = {uds.request_id, uds.response_id, uds.functional_id}
    if uds.enabled and len(ids) < 3:
        raise ptree.ParamError("parameters 'ecu.uds.request_id', 'response_id', 'functional_id' "
                               f"must differ, got {sorted(ids)}")
    check_xcp(tree.ecu.xcp, ids if uds.enabled else set())
    check_ecu_ids(tree.ecu)


HALF_THE_DURATION = math.nan  # RunConfig.kill_tps_at_s's default: half the run, as `vecu run`


@dataclass(frozen=True)
class RunConfig:
    """Everything `vecu run` needs; defaults are the demo's, as `vecu run`'s (10 s, the TPS
    dead at half the duration: kill_tps_at_s left at HALF_THE_DURATION)."""

    duration_s: float = 10.0
    seed: int = 0
    kill_tps_at_s: float | None = HALF_THE_DURATION
    fault: str = "dead"
    fault_value: float | None = None
    realtime: bool = False
    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    log_path: str | None = None
    truth: bool = True  # with log_path: debug truth frames (vecu/dbc/vecu_truth.dbc) in the trace
    keep_series: bool = False
    speed: bool = True  # longitudinal plant part + ECU speed function (Hernandez 2005)
    steering: bool = True  # lateral plant part + ECU steering function (Khalid)
    manifold: bool = True  # engine-event manifold part + ECU manifold function (Dutka 2006)
    kill_swa_at_s: float | None = None
    swa_fault: str = "dead"
    swa_fault_value: float | None = None
    params: ParamTree = field(default_factory=ParamTree)  # plant.* and ecu.* (vecu params)
    speed_manoeuvres: tuple[str, ...] | None = None  # longitudinal plant sequence (None: default)
    faults: tuple[ScheduledFault, ...] = ()  # fault timeline (scenarios), on top of the kills
    uds_steps: tuple[UdsStep, ...] = ()  # a tester's requests (scenarios; docs/uds.md)
    # timed sets of live ecu.* leaves: (at_s, path, value), acting from the ECU's next tick, as
    # an XCP write handled at at_s does (docs/xcp.md)
    calibrations: tuple[tuple[float, str, object], ...] = ()
    xcp_steps: tuple[XcpStep, ...] = ()  # a master's writes and reads (scenarios; docs/xcp.md)
    throttle_input: str | None = None  # a u(t) file driving the throttle (docs/reproduction.md)
    restbus: RestbusConfig | None = None  # a user's bus beside plant and ECU (docs/restbus.md)
    restbus_disturbances: tuple[ScheduledFault, ...] = ()  # its disturbance timeline
    fmu: FmuBinding | None = None  # an FMU as an ECU function (with_fmu; docs/fmu.md)

    def __post_init__(self) -> None:
        if self.kill_tps_at_s is not None and math.isnan(self.kill_tps_at_s):
            object.__setattr__(self, "kill_tps_at_s", self.duration_s / 2)  # frozen: once, here

    def with_params(self, sets: Mapping[str, object] | Iterable[tuple[str, object]] = (),
                    **shortcuts: object) -> RunConfig:
        """This configuration with parameter-tree overrides: (path, value) pairs or a mapping,
        then the shortcuts (noise_scale=, estimator=, manifold_filter=; None: unchanged)."""
        pairs = list(sets.items()) if isinstance(sets, Mapping) else list(sets)
        pairs += shortcut_sets(**shortcuts)
        return replace(self, params=self.params.set(pairs)) if pairs else self

    def with_fmu(self, binding: FmuBinding) -> RunConfig:
        """This configuration with binding's FMU as an ECU function: its parameters become the
        ecu.fmu.<instance> subtree (at the FMU's start values, then the map's [parameters]);
        with_params afterwards overrides them."""
        ecu = replace(self.params.ecu, fmu=parameter_tree(binding))
        params = replace(self.params, ecu=ecu)
        starts = [(f"ecu.fmu.{binding.name}.{k}", v) for k, v in binding.starts]
        return replace(self, fmu=binding, params=ptree.apply_sets(params, starts))

    def default_params(self) -> ParamTree:
        """The default tree of this run's shape (an FMU's subtree at its start values)."""
        return ParamTree(ecu=replace(ecu_params(), fmu=type(self.params.ecu.fmu)()))

    @property
    def estimator(self) -> str:
        return self.params.ecu.throttle.estimator

    def summary(self) -> dict[str, object]:
        """For run summaries: the run's own settings, the throttle noise scale, estimator and
        manifold filter, and every parameter that differs from the defaults (path: value)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "params"}
        out["faults"] = [asdict(f) for f in self.faults]
        out["restbus"] = None if self.restbus is None else {
            "databases": list(self.restbus.databases), "nodes": list(self.restbus.nodes),
            "e2e": self.restbus.e2e_path, "values": self.restbus.values_path}
        out["restbus_disturbances"] = [asdict(d) for d in self.restbus_disturbances]
        out["uds_steps"] = [{k: v.hex(" ") if isinstance(v, bytes) else v
                             for k, v in asdict(u).items()} for u in self.uds_steps]
        out["noise_scale"] = self.params.plant.throttle.noise_scale
        out["estimator"] = self.estimator
        out["manifold_filter"] = self.params.ecu.manifold.filter
        out["fmu"] = None if self.fmu is None else {
            "fmu": self.fmu.fmu, "instance": self.fmu.name, "step_ms": self.fmu.step_ms}
        out["params"] = {leaf.path: leaf.value
                         for leaf in ptree.differences(self.params, self.default_params())}
        return out

    def validate(self) -> None:
        """Raise a UserError (ConfigError, BadArgumentError) on an impossible configuration."""
        if not (self.duration_s > 0 and math.isfinite(self.duration_s)):
            raise ConfigError(f"duration must be a positive number of seconds, got {self.duration_s}")
        if self.duration_s < 1e-3:  # the base tick: a shorter run runs nothing and reports it
            raise ConfigError(f"duration {self.duration_s} s is shorter than one 1 ms tick")
        if self.kill_tps_at_s is not None and not 0 <= self.kill_tps_at_s < self.duration_s:
            raise ConfigError(f"kill time {self.kill_tps_at_s} s is outside the run (0..{self.duration_s} s)")
        validate_tree(self.params)
        if self.throttle_input is not None:  # BadFileError naming the file and the problem
            load_input_file(self.throttle_input)
        if self.kill_swa_at_s is not None and not 0 <= self.kill_swa_at_s < self.duration_s:
            raise ConfigError(f"SWA kill time {self.kill_swa_at_s} s is outside the run "
                              f"(0..{self.duration_s} s)")
        if self.kill_swa_at_s is not None and not self.steering:
            raise ConfigError("an SWA fault needs the steering part (steering=True)")
        for name in (self.fault, self.swa_fault, *(f.kind for f in self.faults)):
            if parse_kind(name) == FaultKind.CLEAR:
                raise ConfigError("fault kind 'clear' cannot be injected")
        if self.kill_tps_at_s is not None:  # a bad value fails now, not at the kill time
            check_value(parse_kind(self.fault), self.fault_value)
        if self.kill_swa_at_s is not None:
            check_value(parse_kind(self.swa_fault), self.swa_fault_value)
        for f in self.faults:
            if not 0 <= f.start_s < self.duration_s:
                raise ConfigError(f"fault {f.kind} on {f.target}: start {f.start_s} s is outside "
                                  f"the run (0..{self.duration_s} s)")
            if f.end_s is not None and not f.start_s < f.end_s:
                raise ConfigError(f"fault {f.kind} on {f.target}: end {f.end_s} s is not after "
                                  f"its start {f.start_s} s")
