"""The FMU map (`--fmu-map MAP.toml`, a scenario's `[fmu]` table) checked against the FMU's
modelDescription.xml (FMI 2.0 section 2.2, FMI 3.0 section 2.4, read by FMPy) and the databases,
before anything runs: every problem is one BadFileError line naming the file and the key.

    [fmu]
    step_ms = 10                 # the communication step, a multiple of the 1 ms tick
    dbc = "outputs.dbc"          # the database holding the output messages (their cycle times)
    databases = ["body.dbc"]     # optional: more databases whose signals feed inputs
    e2e = "E2E.toml"             # optional: output protection, as `vecu restbus --e2e`
    name = "Dahlquist"           # optional: the instance name (default: the FMU file's stem)
    [inputs]                     # FMU input = "MESSAGE.SIGNAL" of any database on the bus
    Float64_continuous_input = "ETB_Wattmeter.ETB_Voltage"
    [outputs]                    # FMU output = "MESSAGE.SIGNAL" of the output database
    Float64_continuous_output = "FMU_Out.FMU_Value"
    [parameters]                 # start values, overridden by --set ecu.fmu.<name>.<variable>
    Float64_tunable_parameter = 1.5

Paths are relative to the map file. A signal's DBC unit and the FMU variable's unit convert
(pint) when both are given and differ.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vecu.codec import TRUTH_DBC, DbcCodec, FrameCodec, builtin_dbc_path
from vecu.e2e import E2EProtection
from vecu.errors import BadFileError, UnavailableError
from vecu.tomlfile import read_toml
from vecu.units import affine

FLOAT_TYPES = frozenset({"Real", "Float32", "Float64"})
INT_TYPES = frozenset({"Integer", "Enumeration", "Int8", "UInt8", "Int16", "UInt16", "Int32",
                       "UInt32", "Int64", "UInt64"})
KIND_OF = {**{t: "float" for t in FLOAT_TYPES}, **{t: "int" for t in INT_TYPES},
           "Boolean": "bool"}
PY_TYPE: dict[str, type] = {"float": float, "int": int, "bool": bool}
MAP_KEYS = {"fmu", "inputs", "outputs", "parameters"}
FMU_KEYS = {"step_ms", "dbc", "databases", "e2e", "name"}
SOURCE = "the FMU's modelDescription.xml ({})"


@dataclass(frozen=True)
class FmuVariable:
    """One scalar variable of the FMU that vecu reads or writes (kind: float, int or bool)."""

    name: str
    vr: int
    fmi_type: str
    kind: str
    causality: str
    variability: str
    start: Any
    unit: str

    @property
    def tunable(self) -> bool:
        """Settable while the FMU runs (FMI 2.0 / 3.0: variability tunable)."""
        return self.variability == "tunable"


@dataclass(frozen=True)
class SignalLink:
    """An FMU variable bound to a DBC signal: the value that flows is `x * scale + offset`
    (inputs: signal -> FMU unit; outputs: FMU -> signal unit)."""

    variable: FmuVariable
    message: str
    signal: str
    scale: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class FmuBinding:
    """An FMU on the bus: the FMU file, its instance name, step, databases and bindings."""

    fmu: str
    name: str
    fmi_version: str
    model_identifier: str
    step_ms: int
    output_dbc: str
    databases: tuple[str, ...] = ()
    e2e_path: str | None = None
    inputs: tuple[SignalLink, ...] = ()
    outputs: tuple[SignalLink, ...] = ()
    parameters: tuple[FmuVariable, ...] = ()  # every numeric parameter: the ecu.fmu subtree
    starts: tuple[tuple[str, Any], ...] = ()  # the map's [parameters] (path under the subtree)
    e2e: Mapping[str, E2EProtection] = field(default_factory=dict)  # output message -> profile

    @property
    def dbcs(self) -> tuple[str, ...]:
        """The databases it adds to the ECU's codec."""
        return (*self.databases, self.output_dbc)


def _fmpy() -> Any:
    try:
        import fmpy
    except ImportError:
        raise UnavailableError("--fmu needs FMPy: pip install 'vecu[fmu]'") from None
    return fmpy


def _variables(md: Any) -> dict[str, FmuVariable]:
    out = {}
    for v in md.modelVariables:
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or ""
        out[v.name] = FmuVariable(v.name, int(v.valueReference), v.type,
                                  KIND_OF.get(v.type, ""), v.causality or "",
                                  v.variability or "", v.start, str(unit))
    return out


def _typed(var: FmuVariable, value: Any) -> Any:
    if var.kind == "bool":
        return value if isinstance(value, bool) else str(value).strip().lower() == "true"
    return PY_TYPE[var.kind](value if value is not None else 0)


def _conversion(path: str, key: str, src: str, dst: str) -> tuple[float, float]:
    """(scale, offset) from unit src to unit dst (vecu.units.affine), or the one-line error."""
    try:
        return affine(src, dst)
    except ImportError:
        raise UnavailableError("unit conversion of an FMU binding needs pint: "
                               "pip install 'vecu[fmu]'") from None
    except ValueError as exc:
        raise BadFileError(path, f"{key}: {exc}") from None


def _fits(var: FmuVariable, sig: Any) -> str | None:
    """Why the signal cannot carry the variable (None: it can)."""
    if not var.kind:
        return f"its FMI type {var.fmi_type} has no CAN signal form (numbers and booleans only)"
    if var.kind == "float":
        return None
    if not sig.integral:
        return (f"it is {var.fmi_type} but the signal {sig.name} carries fractions "
                f"(scale {sig.scale:g}, offset {sig.offset:g})")
    if var.kind == "bool" and ((sig.minimum is not None and sig.minimum < 0)
                               or (sig.maximum is not None and sig.maximum > 1)):
        return f"it is Boolean but the signal {sig.name} ranges beyond 0..1"
    return None


def _link(path: str, section: str, name: str, target: Any, variables: dict[str, FmuVariable],
          causality: str, db: DbcCodec, where: str) -> SignalLink:
    key = f"[{section}] {name}"
    var = variables.get(name)
    if var is None or var.causality != causality:
        known = sorted(v.name for v in variables.values() if v.causality == causality)
        what = "no variable" if var is None else f"{var.causality} variable, not an {causality}"
        raise BadFileError(path, f"{key}: {what} {name!r} in the FMU (its {causality}s: "
                           f"{', '.join(known) or 'none'})")
    if not isinstance(target, str) or target.count(".") != 1:
        raise BadFileError(path, f"{key}: expected \"MESSAGE.SIGNAL\", got {target!r}")
    msg_name, sig_name = target.split(".")
    if msg_name not in db:
        raise BadFileError(path, f"{key}: no message {msg_name!r} in {where}")
    fc: FrameCodec = db[msg_name]
    try:
        sig = fc.signal(sig_name)
    except KeyError:
        raise BadFileError(path, f"{key}: message {msg_name} has no signal {sig_name!r} "
                           f"(signals: {', '.join(s.name for s in fc.signals)})") from None
    problem = _fits(var, sig)
    if problem:
        raise BadFileError(path, f"{key}: does not fit {target}: {problem}")
    src, dst = ((sig.unit or "", var.unit) if causality == "input" else (var.unit, sig.unit or ""))
    scale, offset = _conversion(path, key, src, dst)
    return SignalLink(var, msg_name, sig_name, scale, offset)


def _paths(path: str, base: Path, key: str, value: Any) -> tuple[str, ...]:
    items = value if isinstance(value, list) else [value]
    out = []
    for item in items:
        if not isinstance(item, str):
            raise BadFileError(path, f"[fmu] {key}: expected a file path, got {item!r}")
        p = base / item
        if not p.is_file():
            raise BadFileError(path, f"[fmu] {key}: no such file {str(p)!r}")
        out.append(str(p))
    return tuple(out)


def load_binding(fmu_path: str, map_path: str, table: Mapping[str, Any] | None = None
                 ) -> FmuBinding:
    """The checked binding of fmu_path by the map file (or a scenario's already parsed table,
    map_path then naming the scenario for messages and relative paths)."""
    fmpy = _fmpy()
    if not Path(fmu_path).is_file():
        raise BadFileError(fmu_path, "no such FMU file")
    cfg = dict(table) if table is not None else read_toml(map_path)
    base = Path(map_path).parent
    extra = sorted(set(cfg) - MAP_KEYS)
    if extra:
        raise BadFileError(map_path, f"unknown table {extra[0]!r} (tables: "
                           f"{', '.join(sorted(MAP_KEYS))})")
    head = cfg.get("fmu", {})
    extra = sorted(set(head) - FMU_KEYS)
    if extra:
        raise BadFileError(map_path, f"[fmu]: unknown key {extra[0]!r} (keys: "
                           f"{', '.join(sorted(FMU_KEYS))})")
    try:
        md = fmpy.read_model_description(fmu_path)
    except Exception as exc:  # noqa: BLE001 - FMPy's errors: not a zip, no modelDescription
        raise BadFileError(fmu_path, f"not a readable FMU: {str(exc).splitlines()[0]}") from None
    if md.coSimulation is None:
        raise BadFileError(fmu_path, f"FMI {md.fmiVersion} FMU without co-simulation (model "
                           "exchange only): vecu steps FMUs as co-simulation slaves")
    if md.fmiVersion not in ("2.0", "3.0"):
        raise BadFileError(fmu_path, f"FMI {md.fmiVersion}: vecu runs FMI 2.0 and 3.0 FMUs")
    platforms = fmpy.supported_platforms(fmu_path)
    if fmpy.platform not in platforms:
        raise BadFileError(fmu_path, f"no binary for this platform ({fmpy.platform}; the FMU "
                           f"has: {', '.join(platforms) or 'none'})")
    name = str(head.get("name", Path(fmu_path).stem))
    if not name.isidentifier():
        raise BadFileError(map_path, f"[fmu] name: {name!r} is not a parameter name (letters, "
                           "digits, _): give name = \"...\"")
    step = head.get("step_ms")
    if step is None and md.defaultExperiment is not None and md.defaultExperiment.stepSize:
        step = float(md.defaultExperiment.stepSize) * 1000.0
    if (not isinstance(step, (int, float)) or isinstance(step, bool) or step < 1
            or not float(step).is_integer()):
        raise BadFileError(map_path, f"[fmu] step_ms: expected a whole number of ms >= 1 (a "
                           f"multiple of the 1 ms tick), got {step!r}")
    if "dbc" not in head:
        raise BadFileError(map_path, "[fmu] dbc: the database of the output messages is missing")
    (output_dbc,) = _paths(map_path, base, "dbc", head["dbc"])
    databases = _paths(map_path, base, "databases", head.get("databases", []))
    try:
        out_db = DbcCodec([output_dbc], strict=False)
        on_bus = DbcCodec([builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC), *databases],
                          strict=False)
    except Exception as exc:  # noqa: BLE001 - cantools' parse errors, through the codec
        raise BadFileError(map_path, f"[fmu] databases: {str(exc).splitlines()[0]}") from None
    for key, fc in sorted(out_db.by_id.items()):  # the output DBC joins the ECU's codec whole
        taken = on_bus.by_id.get(key)
        if taken is not None and taken.name != fc.name:
            raise BadFileError(output_dbc, f"{fc.name}: CAN ID 0x{fc.frame_id:X} is "
                               f"{taken.name}'s on the bus already: give it another ID")
    db = DbcCodec([*on_bus.paths, output_dbc], strict=False)
    variables = _variables(md)
    inputs = tuple(_link(map_path, "inputs", k, v, variables, "input", db,
                         "the databases on the bus") for k, v in cfg.get("inputs", {}).items())
    outputs = tuple(_link(map_path, "outputs", k, v, variables, "output", out_db, output_dbc)
                    for k, v in cfg.get("outputs", {}).items())
    if not outputs:
        raise BadFileError(map_path, "[outputs]: no FMU output bound to a signal: the FMU "
                           "would send nothing")
    for msg in sorted({link.message for link in outputs}):
        if not out_db[msg].cycle_time_ms:
            raise BadFileError(output_dbc, f"{msg}: no cycle time (GenMsgCycleTime): an FMU "
                               "output message is sent at its cycle time")
    params = tuple(v for v in variables.values() if v.causality == "parameter" and v.kind
                   and v.name.isidentifier())
    by_name = {p.name: p for p in params}
    starts = []
    for k, v in cfg.get("parameters", {}).items():
        if k not in by_name:
            raise BadFileError(map_path, f"[parameters] {k}: no numeric parameter {k!r} in the "
                               f"FMU (its parameters: {', '.join(by_name) or 'none'})")
        starts.append((k, v))
    from vecu.restbus.spec import parse_e2e, protection_of

    e2e_path = _paths(map_path, base, "e2e", head["e2e"])[0] if "e2e" in head else None
    table_e2e = parse_e2e(e2e_path, out_db) if e2e_path else {}
    e2e: dict[str, E2EProtection] = {}
    for msg in sorted({link.message for link in outputs}):  # the file, ARXML or vecu layout
        prot, _ = protection_of(out_db[msg], table_e2e, output_dbc)
        if prot is not None:
            e2e[msg] = prot
    return FmuBinding(fmu_path, name, md.fmiVersion, md.coSimulation.modelIdentifier,
                      int(step), output_dbc, databases, e2e_path, inputs, outputs, params,
                      tuple(starts), e2e)


@dataclass(frozen=True)
class NoFmu:
    """`ecu.fmu` without an FMU: no leaves."""


_TREES: dict[tuple[str, str, tuple[FmuVariable, ...]], type] = {}


def parameter_tree(binding: FmuBinding) -> Any:
    """The `ecu.fmu` subtree of binding: a frozen dataclass holding one frozen dataclass per
    instance, whose leaves are the FMU's numeric parameters at their modelDescription start
    values (unit from the FMU, source its modelDescription.xml). One class per FMU and
    instance, so that equal trees compare equal; pickled by value (scenario and campaign
    workers rebuild it from the binding)."""
    key = (binding.fmu, binding.name, binding.parameters)
    root = _TREES.get(key)
    if root is None:
        leaves = [(p.name, PY_TYPE[p.kind], field(
            default=_typed(p, p.start),
            metadata={"unit": p.unit or "1", "source": SOURCE.format(Path(binding.fmu).name)}))
            for p in binding.parameters]
        instance = dataclasses.make_dataclass(
            f"FmuParameters_{binding.name}", leaves, frozen=True,
            namespace={"__reduce__": lambda self: (_restore_instance, (
                binding, {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}))})
        root = _TREES[key] = dataclasses.make_dataclass(
            "FmuInstances", [(binding.name, instance, field(default_factory=instance))],
            frozen=True, namespace={"__reduce__": lambda self: (_restore_root, (
                binding, getattr(self, binding.name)))})
    return root()


def _restore_instance(binding: FmuBinding, values: dict[str, Any]) -> Any:
    return dataclasses.replace(getattr(parameter_tree(binding), binding.name), **values)


def _restore_root(binding: FmuBinding, instance: Any) -> Any:
    return dataclasses.replace(parameter_tree(binding), **{binding.name: instance})
