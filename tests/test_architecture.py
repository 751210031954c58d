"""The module contract (docs/architecture.md): every import of every module under vecu/, read with
ast (imports inside functions and under TYPE_CHECKING included), checked against the layering
rules. Each failure names the module and the line."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "vecu"

# cantools API that only codec may touch (attribute names of cantools' Database / Message /
# Signal; `signals` and `senders` are FrameCodec's own plain-data attributes)
CANTOOLS_ATTRS = frozenset({
    "get_signal_by_name", "get_message_by_name", "get_message_by_frame_id",
    "decode_simple", "decode_message", "encode_message", "add_dbc_file", "add_dbc_string",
    "is_extended_frame", "is_multiplexed", "is_container", "receivers", "conversion",
    "cycle_time", "signal_groups", "autosar", "bus_name", "is_float", "byte_order",
})
CANTOOLS_TYPES = frozenset({
    "Database", "Message", "Signal", "Conversion", "LinearConversion", "IdentityConversion",
    "NamedSignalConversion", "NamedSignalValue", "Node", "Bus",
})
SLEEP_OR_CLOCK_CALLS = frozenset({"sleep", "perf_counter", "perf_counter_ns", "process_time",
                                  "process_time_ns", "monotonic", "monotonic_ns", "time_ns"})
FOUNDATION = ("vecu.units", "vecu.rng", "vecu.clock", "vecu.errors", "vecu.argtypes")


@dataclass
class Module:
    name: str  # dotted, a package's __init__ is the package name
    path: Path
    tree: ast.Module
    aliases: dict[str, str] = field(default_factory=dict)  # local name -> dotted import target
    imports: list[tuple[int, str]] = field(default_factory=list)  # (line, dotted target)

    @property
    def rel(self) -> str:
        return str(self.path.relative_to(ROOT))

    def at(self, node: ast.AST) -> str:
        return f"{self.rel}:{getattr(node, 'lineno', 0)}"

    def is_package(self) -> bool:
        return self.path.name == "__init__.py"

    def dotted(self, node: ast.AST) -> str | None:
        """`a.b.c` for a Name/Attribute chain, the head replaced by what it was imported as."""
        parts = []
        while isinstance(node, ast.Attribute):
            parts.append(node.attr)
            node = node.value
        if not isinstance(node, ast.Name):
            return None
        head = self.aliases.get(node.id, node.id)
        return ".".join([head, *reversed(parts)])


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@cache
def modules() -> dict[str, Module]:
    found = {}
    for path in sorted(PKG.rglob("*.py")):
        name = _module_name(path)
        found[name] = Module(name, path, ast.parse(path.read_text(encoding="utf-8"), str(path)))
    for mod in found.values():
        _read_imports(mod, found)
    return found


def _read_imports(mod: Module, known: dict[str, Module]) -> None:
    for node in ast.walk(mod.tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                mod.imports.append((node.lineno, a.name))
                if a.asname:
                    mod.aliases[a.asname] = a.name
                else:
                    head = a.name.split(".")[0]
                    mod.aliases[head] = head
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = mod.name.split(".") if mod.is_package() else mod.name.split(".")[:-1]
                pkg = pkg[:len(pkg) - (node.level - 1)]
                base = ".".join(pkg + ([base] if base else []))
            for a in node.names:
                sub = f"{base}.{a.name}"
                target = sub if sub in known else base
                mod.imports.append((node.lineno, target))
                mod.aliases[a.asname or a.name] = sub
        elif isinstance(node, ast.Call):  # importlib.import_module("vecu.x") with a literal
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in ("import_module", "__import__") and node.args and isinstance(
                    node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                mod.imports.append((node.lineno, node.args[0].value))


def _under(target: str, prefix: str) -> bool:
    return target == prefix or target.startswith(prefix + ".")


def _vecu_imports(mod: Module) -> Iterator[tuple[int, str]]:
    for line, target in mod.imports:
        if _under(target, "vecu"):
            yield line, target


def _report(violations: list[str], rule: str) -> None:
    assert not violations, f"{rule}:\n  " + "\n  ".join(sorted(set(violations)))


# ---------------------------------------------------------------- 1. cantools only in codec

def _codec_private_names() -> set[str]:
    names = set()
    codec = [m for m in modules().values() if _under(m.name, "vecu.codec")]
    for node in (n for m in codec for n in ast.walk(m.tree)):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") \
                and not node.attr.startswith("__"):
            names.add(node.attr)
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name.startswith("_") \
                and not node.name.startswith("__"):
            names.add(node.name)
    return names


def test_cantools_stays_inside_codec():
    private = _codec_private_names() | {"_db", "_message"}
    bad = []
    for mod in modules().values():
        if _under(mod.name, "vecu.codec"):  # the package vecu/codec/
            continue
        for line, target in mod.imports:
            if _under(target, "cantools"):
                bad.append(f"{mod.rel}:{line} imports {target}")
            if _under(target, "vecu.codec") and target.rsplit(".", 1)[-1] in CANTOOLS_TYPES:
                bad.append(f"{mod.rel}:{line} imports the cantools type {target}")
        for node in ast.walk(mod.tree):
            if not isinstance(node, ast.Attribute):
                continue
            owner = node.value.id if isinstance(node.value, ast.Name) else None
            if node.attr in CANTOOLS_ATTRS:
                bad.append(f"{mod.at(node)} uses cantools' .{node.attr} (ask vecu.codec instead)")
            elif node.attr in private and owner not in ("self", "cls"):
                bad.append(f"{mod.at(node)} reaches into codec's private .{node.attr}")
            elif (mod.dotted(node) or "").startswith("vecu.codec.") and (
                    node.attr.startswith("_") or node.attr in CANTOOLS_TYPES):
                bad.append(f"{mod.at(node)} uses vecu.codec.{node.attr}")
    _report(bad, "cantools (or a cantools object) outside vecu/codec/")


# ---------------------------------------------------------------- 2. python-can buses only in bus

def _is_can_bus(dotted: str | None) -> bool:
    if not dotted or not _under(dotted, "can"):
        return False
    last = dotted.rsplit(".", 1)[-1]
    return last.endswith("Bus") or last == "BusABC"


def test_only_bus_module_opens_python_can_buses():
    bad = []
    for mod in modules().values():
        if mod.name == "vecu.bus":
            continue
        for line, target in mod.imports:
            if _under(target, "can.interfaces") or _is_can_bus(target):
                bad.append(f"{mod.rel}:{line} imports {target}")
        for node in ast.walk(mod.tree):
            if isinstance(node, ast.Call) and _is_can_bus(mod.dotted(node.func)):
                bad.append(f"{mod.at(node)} opens a bus: {mod.dotted(node.func)}(...)")
            elif isinstance(node, ast.ClassDef):
                for base in node.bases:
                    if _is_can_bus(mod.dotted(base)):
                        bad.append(f"{mod.at(node)} class {node.name} subclasses "
                                   f"{mod.dotted(base)}")
    _report(bad, "python-can bus opened or subclassed outside vecu/bus.py")


# ---------------------------------------------------------------- 3. time only in clock

def test_only_clock_reads_time_or_sleeps():
    bad = []
    for mod in modules().values():
        if mod.name == "vecu.clock":
            continue
        for line, target in mod.imports:
            if _under(target, "time"):
                bad.append(f"{mod.rel}:{line} imports {target}")
        for node in ast.walk(mod.tree):
            if not isinstance(node, ast.Call):
                continue
            name = mod.dotted(node.func) or ""
            last = name.rsplit(".", 1)[-1]
            if _under(name, "time") or (last in SLEEP_OR_CLOCK_CALLS and not _under(
                    name, "vecu.clock")) or name.endswith(("datetime.now", "datetime.utcnow",
                                                           "date.today")):
                bad.append(f"{mod.at(node)} calls {name}()")
    _report(bad, "time read or sleep outside vecu/clock.py")


# ---------------------------------------------------------------- 4. nothing imports the CLI

def test_nothing_outside_cli_imports_cli():
    bad = [f"{mod.rel}:{line} imports {target}"
           for mod in modules().values()
           if not _under(mod.name, "vecu.cli") and mod.name != "vecu.__main__"  # the entry point
           for line, target in mod.imports if _under(target, "vecu.cli")]
    _report(bad, "vecu.cli imported from outside vecu/cli/")


# ---------------------------------------------------------------- 5. no run-time patching

def _assigned(targets: list[ast.expr]) -> Iterator[ast.Attribute]:
    """Attribute targets of an assignment (tuple / list / starred unpacking included)."""
    for t in targets:
        if isinstance(t, (ast.Tuple, ast.List)):
            yield from _assigned(list(t.elts))
        elif isinstance(t, ast.Starred):
            yield from _assigned([t.value])
        elif isinstance(t, ast.Attribute):
            yield t


def _own_private_attrs(mod: Module) -> set[str]:
    """Private attributes this module's classes set on self (they may set them on siblings)."""
    return {t.attr for node in ast.walk(mod.tree) if isinstance(node, (ast.Assign, ast.AugAssign,
                                                                       ast.AnnAssign))
            for t in _assigned(node.targets if isinstance(node, ast.Assign) else [node.target])
            if t.attr.startswith("_") and isinstance(t.value, ast.Name)
            and t.value.id in ("self", "cls")}


def test_no_run_time_patching():
    """No mock, no patched module / class attributes, no setattr with a computed name, no
    overwriting another module's private attributes: seams are parameters."""
    bad = []
    for mod in modules().values():
        imported = set(mod.aliases)
        own = _own_private_attrs(mod)
        for line, target in mod.imports:
            if _under(target, "unittest.mock") or _under(target, "mock"):
                bad.append(f"{mod.rel}:{line} imports {target}")
        for node in ast.walk(mod.tree):
            targets: list[ast.expr] = []
            if isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            elif isinstance(node, ast.Delete):
                targets = node.targets
            elif isinstance(node, ast.Call):
                name = mod.dotted(node.func) or ""
                last = name.rsplit(".", 1)[-1]
                if last in ("patch", "monkeypatch", "MonkeyPatch") or _under(name, "unittest.mock"):
                    bad.append(f"{mod.at(node)} patches: {name}(...)")
                if name in ("setattr", "delattr") and node.args:
                    first = node.args[0]
                    if isinstance(first, ast.Name) and first.id in imported:
                        bad.append(f"{mod.at(node)} {name}() on the imported {first.id}")
                    elif len(node.args) < 2 or not isinstance(node.args[1], ast.Constant):
                        bad.append(f"{mod.at(node)} {name}() with a computed attribute name")
            for t in _assigned(targets):
                head = t.value
                while isinstance(head, ast.Attribute):
                    head = head.value
                if isinstance(head, ast.Name) and head.id in imported:
                    bad.append(f"{mod.at(t)} assigns {mod.dotted(t)} of an imported "
                               f"module or class")
                elif t.attr.startswith("_") and not t.attr.startswith("__") and t.attr not in own \
                        and not (isinstance(t.value, ast.Name) and t.value.id in ("self", "cls")):
                    bad.append(f"{mod.at(t)} overwrites another module's private .{t.attr}")
    _report(bad, "run-time patching in vecu/ (pass a seam explicitly instead)")


# ---------------------------------------------------------------- 6. no import cycles

def _graph() -> dict[str, set[str]]:
    mods = modules()
    graph: dict[str, set[str]] = {name: set() for name in mods}
    for mod in mods.values():
        for _, target in _vecu_imports(mod):
            while target not in mods and "." in target:
                target = target.rsplit(".", 1)[0]
            if target in mods and target != mod.name:
                graph[mod.name].add(target)
    return graph


def _strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative; components of more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        top = stack.pop()
                        on_stack.discard(top)
                        comp.append(top)
                        if top == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_no_import_cycles():
    graph = _graph()
    mods = modules()
    bad = []
    for comp in _strongly_connected(graph):
        edges = []
        for name in comp:
            for line, target in _vecu_imports(mods[name]):
                if any(_under(target, other) for other in comp if other != name):
                    edges.append(f"{mods[name].rel}:{line} -> {target}")
        bad.append("cycle " + " <-> ".join(comp) + ": " + "; ".join(sorted(set(edges))))
    _report(bad, "import cycles")


def test_tarjan_finds_a_planted_cycle():
    assert _strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [
        ["a", "b", "c"]]


# ---------------------------------------------------------------- 7. layering

def _layer_violations(prefix: str, allowed: tuple[str, ...] | None,
                      forbidden: tuple[str, ...] = ()) -> list[str]:
    bad = []
    for mod in modules().values():
        if not _under(mod.name, prefix):
            continue
        for line, target in _vecu_imports(mod):
            if allowed is not None and not any(_under(target, a) for a in allowed):
                bad.append(f"{mod.rel}:{line} imports {target} ({prefix} may import only "
                           f"{', '.join(allowed) or 'nothing of vecu'})")
            if any(_under(target, f) for f in forbidden):
                bad.append(f"{mod.rel}:{line} imports {target} ({prefix} must not)")
    return bad


def test_layering():
    bad = _layer_violations("vecu.models", ("vecu.units", "vecu.kernels", "vecu.models"))
    bad += _layer_violations("vecu.estimators", None, (
        "vecu.plant", "vecu.bus", "vecu.codec", "vecu.ecu", "vecu.cli"))
    bad += _layer_violations("vecu.plant", None, ("vecu.estimators",))
    bad += _layer_violations("vecu.ecu", None, ("vecu.plant",))
    # the UDS server stands on the ECU (floor 5); the ECU knows it only as a Protocol
    bad += _layer_violations("vecu.uds", None, ("vecu.plant", "vecu.estimators.registry"))
    bad += _layer_violations("vecu.ecu", None, ("vecu.uds", "vecu.xcp"))
    # the restbus stands beside the plant (floor 5): never the ECU, estimators or plant
    bad += _layer_violations("vecu.restbus", None, (
        "vecu.ecu", "vecu.estimators", "vecu.plant", "vecu.uds", "vecu.runner"))
    # the XCP slave stands on the ECU too (floor 5), beside the UDS server
    bad += _layer_violations("vecu.xcp", None, ("vecu.plant", "vecu.estimators.registry",
                                                "vecu.uds"))
    # an FMU is an ECU function (floor 5, ECU side): never the plant, estimators or servers
    # (its output protection reads a restbus E2E file: vecu.restbus.spec)
    bad += _layer_violations("vecu.fmu", None, ("vecu.plant", "vecu.estimators", "vecu.uds",
                                                "vecu.xcp", "vecu.runner"))
    # the gateway routes into the ECUs' diagnostic channels on CAN: never the plant
    bad += _layer_violations("vecu.gateway", None, ("vecu.plant", "vecu.cli"))
    for name in FOUNDATION:
        bad += _layer_violations(name, ())
    _report(bad, "layering (docs/architecture.md)")


def test_the_walk_sees_every_module_and_nested_imports():
    mods = modules()
    assert {"vecu.codec", "vecu.bus", "vecu.clock", "vecu.cli", "vecu.runner"} <= set(mods)
    nested = [t for m in mods.values() for n in ast.walk(m.tree)
              if isinstance(n, ast.FunctionDef)
              for s in ast.walk(n) if isinstance(s, (ast.Import, ast.ImportFrom))
              for t in [s]]
    assert nested, "expected imports inside functions somewhere in vecu/"
    listed = {(m.name, line) for m in mods.values() for line, _ in m.imports}
    assert all((m.name, s.lineno) in listed for m in mods.values() for n in ast.walk(m.tree)
               if isinstance(n, ast.FunctionDef) for s in ast.walk(n)
               if isinstance(s, (ast.Import, ast.ImportFrom)))


# ---------------------------------------------------------------- 8. the floor map

# docs/architecture.md's floor map: every top-level module or package of vecu/ on one floor.
# A module imports its own floor and the floors below, never a higher one (the wall between the
# plant and the estimators/ECU is held by test_layering).
FLOORS: dict[int, tuple[str, ...]] = {
    0: ("errors", "units", "rng", "clock", "kernels", "stats", "argtypes", "tomlfile", "shipped",
        "instances", "data"),
    1: ("models",),
    2: ("params",),
    3: ("bus", "codec", "e2e", "can_message", "fault_kinds",
        "faults", "scheduler", "recorder"),
    4: ("estimators",),
    5: ("plant", "restbus", "ecu", "uds", "xcp", "fmu"),
    6: ("config", "assembly", "runner", "probes", "summary", "warmup", "functions"),
    7: ("replay", "scenario", "campaign", "eval", "bench", "live", "plot", "figures", "ident",
        "gateway", "simulation", "pytest_plugin", "conformance", "fleet"),
    8: ("cli", "__main__"),
}
FLOOR_OF = {name: floor for floor, names in FLOORS.items() for name in names}


def _top(dotted: str) -> str | None:
    parts = dotted.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "vecu" else None


def test_every_module_is_on_a_floor():
    tops = {p.stem if p.suffix == ".py" else p.name for p in PKG.iterdir()
            if (p.suffix == ".py" and p.name != "__init__.py")
            or (p.is_dir() and (p / "__init__.py").exists())}
    missing = sorted(tops - set(FLOOR_OF))
    gone = sorted(set(FLOOR_OF) - tops)
    assert not missing, f"modules on no floor (add them to FLOORS and docs/architecture.md): {missing}"
    assert not gone, f"FLOORS names modules that do not exist: {gone}"


def test_no_import_reaches_a_higher_floor():
    bad = []
    for mod in modules().values():
        here = _top(mod.name)
        if here is None:
            continue
        for line, target in _vecu_imports(mod):
            there = _top(target)
            if there in FLOOR_OF and FLOOR_OF[there] > FLOOR_OF[here]:
                bad.append(f"{mod.rel}:{line} imports {target} (floor {FLOOR_OF[there]} above "
                           f"{here}'s {FLOOR_OF[here]})")
    _report(bad, "floors (docs/architecture.md)")


def test_the_documented_floor_map_names_every_module_on_its_floor():
    """The diagram in docs/architecture.md: each floor's rows (between its rules) name exactly
    the modules FLOORS puts there (`name.py` or `name/`)."""
    doc = (ROOT / "docs" / "architecture.md").read_text()
    diagram = doc.split("```")[1]
    rows: dict[int, str] = {}
    floor = None
    for line in diagram.splitlines():
        head = re.match(r"\s*(\d)\s", line)
        if head:
            floor = int(head.group(1))
        elif "─" in line:
            floor = None
        if floor is not None and "│" in line:
            rows[floor] = rows.get(floor, "") + " " + line.replace("║", " ")
    bad = []
    for floor, names in FLOORS.items():
        text = rows.get(floor, "")
        for name in names:
            if f"{name}.py" not in text and f"{name}/" not in text:
                bad.append(f"floor {floor} row does not name {name}")
        for other, f in FLOOR_OF.items():
            if f != floor and (f" {other}.py" in text or f" {other}/" in text):
                bad.append(f"floor {floor} row names {other}, which FLOORS puts on {f}")
    _report(bad, "the floor map in docs/architecture.md")
