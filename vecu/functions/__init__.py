"""The ECU's functions by name, python-can's BACKENDS habit: FUNCTIONS maps each name to the
"module:attribute" of its EcuFunctionSpec (vecu.functions.base), loaded on first use, so that
reading the names (command-line options) imports nothing heavy. A new function is its folder
plus one line in FUNCTIONS; outside vecu, an installed package's entry point in the group
`vecu.functions` (python-can's `can.interface` habit: name = "module:SPEC", found through
importlib.metadata, loaded on first use; one that fails to load is one warning naming it and
is left out), or a `register()` call (a test's toy function; `registered()` undoes it on exit).

The order is the ECU's: functions are built, run within a tick and scheduled in it.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from vecu.params import add_ecu_subtrees

if TYPE_CHECKING:
    from vecu.codec import DbcCodec
    from vecu.config import RunConfig
    from vecu.functions.base import EcuFunctionSpec, Sensor

FUNCTIONS: dict[str, str] = {
    "throttle": "vecu.functions.throttle:SPEC",
    "speed": "vecu.functions.speed:SPEC",
    "steering": "vecu.functions.steering:SPEC",
    "manifold": "vecu.functions.manifold:SPEC",
    "fmu": "vecu.functions.fmu:SPEC",  # a user's FMU (RunConfig.fmu; docs/fmu.md)
}
# the built-in functions a run may leave out: RunConfig.<name>, `--no-<name>` of the live tools
OPTIONAL: tuple[str, ...] = ("speed", "steering", "manifold")
_loaded: dict[str, EcuFunctionSpec] = {}   # FUNCTIONS' specs imported so far
_plugins: dict[str, EcuFunctionSpec] = {}  # register()ed, after the built-in ones
_codecs: dict[tuple, DbcCodec] = {}  # codecs with plug-ins' DBCs, built once per DBCs + instance
ENTRY_POINT_GROUP = "vecu.functions"
_entry_points: dict[str, Any] | None = None  # installed plug-ins by name, found on first use
_broken: dict[str, str] = {}  # plug-ins that failed to load: name -> why
log = logging.getLogger(__name__)

__all__ = ["ENTRY_POINT_GROUP", "FUNCTIONS", "OPTIONAL", "PluginInfo", "enabled",
           "function_codec", "names", "plugins", "register", "registered", "sensors", "spec",
           "specs", "unregister"]


@dataclass(frozen=True)
class PluginInfo:
    """An installed plug-in: its entry point, the package that brings it, its state."""

    name: str
    target: str   # "module:attribute"
    package: str
    version: str
    error: str | None  # why it did not load (None: loaded)


def _installed() -> dict[str, Any]:
    """The entry points of the group `vecu.functions` (importlib.metadata), once per process;
    one named like a built-in function is left out with a warning."""
    global _entry_points
    if _entry_points is None:
        from importlib.metadata import entry_points

        found: dict[str, Any] = {}
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            if ep.name in FUNCTIONS or ep.name in found:
                _fail(ep, f"the name {ep.name!r} is taken")
                continue
            found[ep.name] = ep
        _entry_points = found
    return _entry_points


def _package(ep: Any) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    return (dist.name, dist.version) if dist is not None else ("?", "?")


def _fail(ep: Any, why: str) -> None:
    package, version = _package(ep)
    _broken[ep.name] = why
    log.warning("plug-in %r (%s %s, %s) not loaded: %s; vecu runs without it", ep.name,
                package, version, ep.value, why)


def _load(name: str) -> EcuFunctionSpec | None:
    """The installed plug-in called name, loaded once (None: it failed, warned once)."""
    from vecu.functions.base import EcuFunctionSpec

    if name in _broken:
        return None
    if name not in _loaded:
        ep = _installed()[name]
        try:
            obj = ep.load()
        except Exception as exc:  # noqa: BLE001 - any failure of a third party's import
            _fail(ep, f"{type(exc).__name__}: {exc}".splitlines()[0])
            return None
        if not isinstance(obj, EcuFunctionSpec):
            _fail(ep, f"{ep.value} is a {type(obj).__name__}, not an EcuFunctionSpec")
            return None
        if obj.name != name:
            _fail(ep, f"its spec is named {obj.name!r}, the entry point {name!r}")
            return None
        _loaded[name] = obj
    return _loaded[name]


def plugins() -> list[PluginInfo]:
    """Every installed plug-in (each loaded to tell whether it works)."""
    out = []
    for name, ep in _installed().items():
        _load(name)
        out.append(PluginInfo(name, ep.value, *_package(ep), _broken.get(name)))
    return out


def names() -> tuple[str, ...]:
    """Every function's name, in the ECU's order: built-in, installed plug-ins, registered
    (only the entry points' metadata is read; nothing imported)."""
    return (*FUNCTIONS, *(n for n in _installed() if n not in _broken), *_plugins)


def spec(name: str) -> EcuFunctionSpec:
    """The function called name (KeyError naming the known ones, or why a plug-in failed)."""
    if name in _plugins:
        return _plugins[name]
    if name in _installed() and name not in FUNCTIONS:
        found = _load(name)
        if found is None:
            raise KeyError(f"plug-in {name!r} did not load: {_broken[name]}")
        return found
    if name not in FUNCTIONS:
        raise KeyError(f"no ECU function {name!r} (known: {', '.join(names())})")
    if name not in _loaded:
        module, attr = FUNCTIONS[name].split(":")
        _loaded[name] = getattr(importlib.import_module(module), attr)
    return _loaded[name]


def specs() -> tuple[EcuFunctionSpec, ...]:
    """Every function that loads, in the ECU's order (a broken plug-in is left out, warned)."""
    out = []
    for name in names():
        if name in FUNCTIONS or name in _plugins:
            out.append(spec(name))
        else:
            found = _load(name)
            if found is not None:
                out.append(found)
    return tuple(out)


def enabled(config: RunConfig) -> tuple[EcuFunctionSpec, ...]:
    """The functions config's run has."""
    return tuple(s for s in specs() if s.enabled(config))


def sensors() -> dict[str, tuple[str, Sensor]]:
    """Every diagnosed sensor by short name, by rank: (its function's name, the sensor)."""
    found = [(short, (s.name, sensor)) for s in specs() for short, sensor in s.sensors.items()]
    return dict(sorted(found, key=lambda item: item[1][1].rank))


def register(new: EcuFunctionSpec) -> None:
    """Add a function after the registered ones (ValueError if its name is taken)."""
    if new.name in names():
        raise ValueError(f"an ECU function {new.name!r} is registered already")
    _plugins[new.name] = new


def unregister(name: str) -> None:
    """Remove a function register() added (the built-in ones stay)."""
    if name in FUNCTIONS:
        raise ValueError(f"{name!r} is a built-in ECU function")
    _plugins.pop(name, None)


@contextmanager
def registered(new: EcuFunctionSpec) -> Iterator[EcuFunctionSpec]:
    """register(new) for the with block, unregistered after it."""
    register(new)
    try:
        yield new
    finally:
        unregister(new.name)


def _plugin_subtrees() -> dict[str, Any]:
    """{name: factory} of the plug-ins' calibrations (vecu.config.ecu_params adds them)."""
    found = [_load(name) for name in _installed() if name not in _broken]
    found += list(_plugins.values())  # the built-in specs are not imported for this
    return {s.name: s.params for s in found if s is not None and s.params is not None}


add_ecu_subtrees(_plugin_subtrees)


def function_codec(instance: int = 0, config: RunConfig | None = None) -> DbcCodec:
    """vecu's codec (its DBC and truth DBC), with the DBCs of registered plug-ins that bring
    their own messages and those config's run adds (an FMU's); the shared codec when none does.
    instance: the ECU instance whose frames it sends and reads (vecu.instances; 0: the DBCs'
    IDs)."""
    from vecu.codec import TRUTH_DBC, DbcCodec, builtin_dbc_path, shared_codec

    extra = tuple(path for s in specs() for path in s.dbc)
    if config is not None:
        extra += tuple(path for s in enabled(config) if s.run_dbc is not None
                       for path in s.run_dbc(config))
        extra = tuple(dict.fromkeys(extra))
    if not extra:
        return shared_codec(instance)
    codec = _codecs.get((*extra, instance))
    if codec is None:
        codec = _codecs[(*extra, instance)] = DbcCodec(
            [builtin_dbc_path(), builtin_dbc_path(TRUTH_DBC), *extra], instance=instance)
    return codec
