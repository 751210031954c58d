"""The parameter tree's mechanics: dotted paths over nested frozen dataclasses.

Every leaf of the tree (vecu.config.ParamTree: `plant.*` the simulated car, `ecu.*` what the ECU
believes) has a dotted path, a value, a unit and a source. `leaves()` lists them, `apply_sets()`
returns a new tree with `PATH=VALUE` overrides (parsed to the leaf's type and checked), and an
unknown path or a bad value is a `ParamError` naming the path and the nearest valid names.

Units come from the field's metadata (`unit`), else from the name's suffix (`_s` s, `_kpa` kPa …),
else "1" for a plain number; sources from the field's metadata (`source`), else from the nearest
entry of `SOURCES` (longest path prefix). tests/test_params.py checks that every leaf has both.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from vecu.errors import BadArgumentError

UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_w_per_k", "W/K"), ("_n_per_rad", "N/rad"), ("_kgm2", "kg m^2"), ("_mps2", "m/s^2"),
    ("_mps", "m/s"), ("_kmh", "km/h"), ("_rpm", "rpm"), ("_kpa", "kPa"), ("_dm3", "dm^3"),
    ("_deg", "deg"), ("_rad", "rad"), ("_ms", "ms"), ("_hz", "Hz"), ("_kg", "kg"), ("_m", "m"),
    ("_s", "s"), ("_v", "V"), ("_k", "K"),
)

# Longest matching prefix wins. Paper parameters cite the paper's equation/table; the rest are
# vecu decisions with the docs/models.md (or docs/scenarios.md) section that explains them.
SOURCES: dict[str, str] = {
    "plant.throttle": "Vargas 2015 Section III-B (noise F); vecu decision (TPS noise), "
                      "docs/models.md 'Throttle'",
    "plant.throttle.model": "Vargas 2015 eq. 3, Table I",
    "plant.input": "Vargas 2015 Section III-B (excitation)",
    "plant.sensors.tps": "vecu decision, docs/models.md 'TPS transfer law'",
    "plant.sensors.wheel": "Hernandez 2005 Section 2.2.2; vecu decision, docs/models.md "
                           "'Vehicle speed and acceleration'",
    "plant.sensors.accel": "Hernandez 2005 Section 2.1.2; vecu decision, docs/models.md "
                           "'Vehicle speed and acceleration'",
    "plant.sensors.lateral": "shared/design/steering.md; Khalid eq. 3 (Y = G Y0 + nu)",
    "plant.lateral": "Khalid Section III (M, I_z); shared/design/steering.md (the rest)",
    "plant.driveline": "vecu decision, docs/models.md 'One car'",
    "plant.manifold": "Dutka 2006 eq. 1-9; engine values shared/design/manifold.md",
    "plant.manifold.noise": "Dutka 2006 Section IV (Q, R)",
    "plant.manifold.noise_scale": "vecu decision (1 = the paper's Q and R)",
    "ecu": "vecu decision, docs/scenarios.md 'Diagnostics'",
    "ecu.rx": "vecu decision, docs/live.md 'Floods'",
    "ecu.throttle.calibration": "vecu decision, docs/models.md 'TPS transfer law'",
    "ecu.throttle.estimator": "vecu decision, docs/models.md 'Production throttle estimator'",
    "ecu.throttle.noise_scale": "Vargas 2015 Section III-B (alpha scales F)",
    "ecu.throttle.model": "Vargas 2015 eq. 3, Table I (the ECU's calibration; `vecu identify "
                          "throttle` fits it to a trace, docs/reproduction.md)",
    "ecu.speed.filter": "vecu decision, docs/models.md 'Vehicle speed and acceleration' "
                        "(after Hernandez 2005 eq. 24-25)",
    "ecu.steering.lag_s": "vecu decision, docs/models.md 'Steering'",
    "ecu.steering.model": "vecu decision, docs/models.md 'Steering' (Khalid UKF tuning)",
    "ecu.steering.model.params": "Khalid Section III (M, I_z); shared/design/steering.md (the rest)",
    "ecu.manifold": "Dutka 2006 eq. 1-9; engine values shared/design/manifold.md",
    "ecu.manifold.noise": "Dutka 2006 Section IV (Q, R)",
    "ecu.manifold.filter": "Dutka 2006 Section III (EKF, SDKF); docs/models.md 'Intake manifold'",
    "ecu.manifold.kf": "vecu decision, docs/models.md 'Intake manifold' (guards, gating)",
    "ecu.manifold.kf.params": "Dutka 2006 eq. 1-9; engine values shared/design/manifold.md",
    "ecu.manifold.kf.noise": "Dutka 2006 Section IV (Q, R)",
    "ecu.manifold.kf.eta_q": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.eta_p0": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.eta_box": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.eta_pr_freeze": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.eta_alpha_gate": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.ta_gain_p0": "Dutka 2006 Table 2 (alpha +-3 %); docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.ta_gain_box": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.act_p0": "Dutka 2006 Table 2 (zeta_T, omega_T +-5 %); docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.act_box": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.act_q": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.eta_drift_prior": "vecu decision, docs/models.md 'Adaptive air charge'",
    "ecu.manifold.kf.eta_slab_sd": "Dutka 2006 Table 2 (eta +-4 %); docs/models.md 'Adaptive air charge'",
    "ecu.instance": "ISO 15765-4 (OBD CAN IDs 0x7E0-0x7EF); vecu decision, docs/live.md "
                    "'Several ECUs on one bus'",
    "ecu.uds": "ISO 14229-1 (UDS), ISO 15765-2 (ISO-TP); vecu decision, docs/uds.md",
    "ecu.xcp": "ASAM MCD-1 XCP 1.5 on CAN; vecu decision, docs/xcp.md",
}

# Units of names that carry none in a suffix (model units where a paper defines its own).
NAME_UNITS: dict[str, str] = {
    "v_at_0": "V", "v_at_90": "V", "omega0": "rad/s", "r_air": "J/(kg K)", "q_jerk": "(m/s^3)^2/Hz",
    "q_offset": "(m/s^2)^2/s", "p_box": "kPa", "t_box": "K", "alpha_box": "rad", "n_range": "rpm",
    "q_et": "rad^2", "q_im": "(kPa^2, K^2)", "q_tmeas": "K^2", "r_ta": "rad^2", "r_pim": "kPa^2",
    "r_tim": "K^2", "cd_alpha_deg": "deg", "eta_n_rpm": "rpm", "q_delta": "rad^2",
    "q_vy": "(m/s)^2", "q_r": "(rad/s)^2", "sigma_r": "rad/s", "sigma_ay": "m/s^2",
    "max_abs_r": "rad/s", "max_abs_ay": "m/s^2", "max_abs_delta": "rad", "max_v_x": "m/s",
    "plaus_margin": "signal unit (deg, km/h)", "dt_s": "s",
    "y_ranges": "(rad, kPa, K)", "p0_diag": "(rad^2, kPa^2, K^2)", "p0_std": "SI",
    "eta_q": "1 (variance of c per event)", "eta_p0": "1 (variance of c)",
    "eta_box": "1 (c = eta_true / eta_calibrated)", "eta_pr_freeze": "1 (P_im / P_a)",
    "eta_alpha_gate": "sigma (normalised TA innovation)",
    "ta_gain_p0": "1 (variance of g, TA = g alpha)", "ta_gain_box": "1 (g)",
    "act_p0": "1 (variance of k_zeta, k_omega)", "act_box": "1 (k = actual / calibrated)",
    "act_q": "1 (variance per event)", "eta_drift_prior": "1 (probability)",
    "eta_slab_sd": "1 (sd of c)",
}


# Sane bounds per leaf: a value a run cannot honour (a time that overflows the ns clock, a noise
# scale whose square overflows, a count beyond any run) is refused when it is set. The field's
# metadata "bounds" (lo, hi) wins; else times by unit (0 .. 1e7 s, ~116 days), scales by name
# (0 .. 1e3), and any other number within +-MAX_MAGNITUDE.
MAX_TIME_S = 1e7
MAX_SCALE = 1e3
MAX_MAGNITUDE = 1e9
UNIT_BOUNDS: dict[str, tuple[float, float]] = {"s": (0.0, MAX_TIME_S), "ms": (0.0, MAX_TIME_S * 1e3)}


# ecu.* subtrees beyond the ECU's own fields: plug-in functions' calibrations. vecu.functions
# adds a source of them on import; each source gives {name: factory of the subtree}
SubtreeSource = Callable[[], Mapping[str, Callable[[], Any]]]
_SUBTREE_SOURCES: list[SubtreeSource] = []


def add_ecu_subtrees(source: SubtreeSource) -> None:
    """Register a source of extra ecu.<name> subtrees (the registry of ECU functions)."""
    if source not in _SUBTREE_SOURCES:
        _SUBTREE_SOURCES.append(source)


def ecu_subtrees() -> tuple[tuple[str, Callable[[], Any]], ...]:
    """(name, factory) of every extra ecu.<name> subtree, in the sources' order."""
    return tuple((name, factory) for source in _SUBTREE_SOURCES
                 for name, factory in source().items())


class ParamError(BadArgumentError):
    """An unknown parameter path or a value that does not fit it (one line, exit 2)."""


@dataclass(frozen=True)
class Leaf:
    """One parameter: its dotted path, value, unit and source."""

    path: str
    value: Any
    unit: str
    source: str


def _is_tree(obj: Any) -> bool:
    return dataclasses.is_dataclass(obj) and not isinstance(obj, type)


def _fields(obj: Any) -> Iterator[dataclasses.Field]:
    for f in dataclasses.fields(obj):
        if f.init and f.metadata.get("param", True):
            yield f


def unit_of(name: str, field: dataclasses.Field | None = None) -> str:
    if field is not None and "unit" in field.metadata:
        return field.metadata["unit"]
    if name in NAME_UNITS:
        return NAME_UNITS[name]
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return "1"


def source_of(path: str, field: dataclasses.Field | None = None) -> str:
    if field is not None and "source" in field.metadata:
        return field.metadata["source"]
    parts = path.split(".")
    for n in range(len(parts), 0, -1):
        src = SOURCES.get(".".join(parts[:n]))
        if src is not None:
            return src
    return ""


def bounds_of(path: str, field: dataclasses.Field | None = None) -> tuple[float, float]:
    """(lo, hi) a number at this leaf (each number of a tuple leaf) must lie within."""
    if field is not None and "bounds" in field.metadata:
        return field.metadata["bounds"]
    name = path.rsplit(".", 1)[-1].split("[")[0]
    unit = unit_of(name, field)
    if unit in UNIT_BOUNDS:
        return UNIT_BOUNDS[unit]
    if name.endswith("scale"):
        return (0.0, MAX_SCALE)
    return (-MAX_MAGNITUDE, MAX_MAGNITUDE)


def _check_bounds(path: str, value: float, bounds: tuple[float, float] | None) -> None:
    if bounds is None:
        return
    lo, hi = bounds
    if not lo <= value <= hi:
        unit = unit_of(path.rsplit(".", 1)[-1].split("[")[0])
        what = f" {unit}" if unit != "1" and not unit.startswith(("(", "1 (")) else ""
        raise ParamError(f"parameter '{path}' must be >= {lo:g} and <= {hi:g}{what}, got {value:g}")


def leaves(tree: Any, prefix: str = "") -> Iterator[Leaf]:
    """Every leaf of a tree of frozen dataclasses, depth first in field order."""
    for f in _fields(tree):
        value = getattr(tree, f.name)
        path = f"{prefix}{f.name}"
        if _is_tree(value):
            yield from leaves(value, path + ".")
        else:
            yield Leaf(path, value, unit_of(f.name, f), source_of(path, f))


def paths(tree: Any) -> list[str]:
    return [leaf.path for leaf in leaves(tree)]


def get(tree: Any, path: str) -> Any:
    """The value at a dotted path (a leaf or a subtree)."""
    node = tree
    for part in path.split("."):
        if not _is_tree(node) or part not in {f.name for f in _fields(node)}:
            raise _unknown(tree, path)
        node = getattr(node, part)
    return node


def _unknown(tree: Any, path: str) -> ParamError:
    known = paths(tree)
    near = difflib.get_close_matches(path, known, n=3, cutoff=0.5)
    if not near:  # same last name anywhere in the tree
        tail = path.rsplit(".", 1)[-1]
        near = [p for p in known if p.rsplit(".", 1)[-1] == tail][:3]
    hint = f"; nearest: {', '.join(near)}" if near else "; `vecu params` lists them all"
    return ParamError(f"unknown parameter '{path}'{hint}")


def parse_value(path: str, text: Any, current: Any,
                bounds: tuple[float, float] | None = None) -> Any:
    """`text` (a string from the command line, or a TOML value) converted to current's type;
    numbers checked against `bounds` (lo, hi) when given (see bounds_of)."""
    kind = type(current)
    try:
        if isinstance(current, bool):
            if isinstance(text, bool):
                return text
            low = str(text).strip().lower()
            if low in ("true", "1", "yes", "on"):
                return True
            if low in ("false", "0", "no", "off"):
                return False
            raise ValueError
        if isinstance(current, int):
            if isinstance(text, bool):
                raise TypeError
            if isinstance(text, str) and text.strip().lower().startswith(("0x", "-0x")):
                text = int(text, 16)  # CAN IDs: ecu.uds.request_id=0x7E0
            value = int(text) if not isinstance(text, float) or text.is_integer() else None
            if value is None:
                raise TypeError
            _check_bounds(path, value, bounds)
            return value
        if isinstance(current, float):
            if isinstance(text, bool):
                raise TypeError
            value = float(text)
            if not math.isfinite(value):
                raise ParamError(f"parameter '{path}': expected a finite number, got {text}")
            _check_bounds(path, value, bounds)
            return value
        if isinstance(current, str):
            return str(text)
        if isinstance(current, tuple):
            items = text if isinstance(text, (list, tuple)) else str(text).split(",")
            if len(items) != len(current):
                raise ParamError(f"parameter '{path}': expected {len(current)} values, "
                                 f"got {len(items)}")
            return tuple(parse_value(f"{path}[{i}]", v, c, bounds)
                         for i, (v, c) in enumerate(zip(items, current)))
    except ParamError:
        raise
    except (TypeError, ValueError):
        pass
    raise ParamError(f"parameter '{path}': expected {_kind_name(kind)}, got {text!r}")


def _kind_name(kind: type) -> str:
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string",
            tuple: "a comma-separated list"}.get(kind, kind.__name__)


def _replace(node: Any, parts: list[str], value: Any, tree: Any, path: str) -> Any:
    name = parts[0]
    if not _is_tree(node) or name not in {f.name for f in _fields(node)}:
        raise _unknown(tree, path)
    child = getattr(node, name)
    if len(parts) == 1:
        if _is_tree(child):
            raise ParamError(f"'{path}' is a group, not a parameter; set one of: "
                             f"{', '.join(paths(child)[:6])}")
        fld = next(f for f in _fields(node) if f.name == name)
        new = parse_value(path, value, child, bounds_of(path, fld))
    else:
        new = _replace(child, parts[1:], value, tree, path)
    try:
        return dataclasses.replace(node, **{name: new})
    except (TypeError, ValueError) as exc:  # a config's own __post_init__ check
        raise ParamError(f"parameter '{path}' = {value!r}: {exc}") from None


def apply_sets(tree: Any, sets: Mapping[str, Any] | Iterable[tuple[str, Any]]) -> Any:
    """A new tree with each (path, value) applied in order; values are parsed to the leaf type."""
    items = sets.items() if isinstance(sets, Mapping) else sets
    for path, value in items:
        tree = _replace(tree, path.split("."), value, tree, path)
    return tree


def parse_set_args(args: Iterable[str]) -> list[tuple[str, str]]:
    """`PATH=VALUE` strings (from `--set`) as (path, value) pairs."""
    out = []
    for arg in args:
        path, sep, value = arg.partition("=")
        if not sep or not path.strip():
            raise ParamError(f"--set expects PATH=VALUE, got {arg!r}")
        out.append((path.strip(), value.strip()))
    return out


def flatten_toml(table: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """A TOML `[set]` table (nested or with dotted keys) as (path, value) pairs."""
    out: list[tuple[str, Any]] = []
    for key, value in table.items():
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.extend(flatten_toml(value, path + "."))
        else:
            out.append((path, value))
    return out


def differences(tree: Any, reference: Any) -> list[Leaf]:
    """Leaves of tree whose value differs from the same path in reference."""
    ref = {leaf.path: leaf.value for leaf in leaves(reference)}
    return [leaf for leaf in leaves(tree) if ref.get(leaf.path) != leaf.value]
