"""The ECU's functions by name, python-can's BACKENDS habit: FUNCTIONS maps each name to the
"module:attribute" of its EcuFunctionSpec (vecu.functions.base), loaded on first use, so that
reading the names (command-line options) imports nothing heavy. A new function is its folder
plus one line in FUNCTIONS, or a `register()` call (a plug-in outside vecu, a test's toy
function; `registered()` undoes it on exit).

The order is the ECU's: functions are built, run within a tick and scheduled in it.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

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

__all__ = ["FUNCTIONS", "OPTIONAL", "enabled", "function_codec", "names", "register",
           "registered", "sensors", "spec", "specs", "unregister"]


def names() -> tuple[str, ...]:
    """Every registered function's name, in the ECU's order (nothing imported)."""
    return (*FUNCTIONS, *_plugins)


def spec(name: str) -> EcuFunctionSpec:
    """The function called name (KeyError naming the known ones)."""
    if name in _plugins:
        return _plugins[name]
    if name not in FUNCTIONS:
        raise KeyError(f"no ECU function {name!r} (known: {', '.join(names())})")
    if name not in _loaded:
        module, attr = FUNCTIONS[name].split(":")
        _loaded[name] = getattr(importlib.import_module(module), attr)
    return _loaded[name]


def specs() -> tuple[EcuFunctionSpec, ...]:
    """Every registered function, in the ECU's order."""
    return tuple(spec(name) for name in names())


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
