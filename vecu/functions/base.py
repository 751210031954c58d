"""EcuFunctionSpec: everything the harness needs to know of one ECU function, so that a new
function is its folder plus one registry entry (vecu.functions.FUNCTIONS).

The runner, the trace replay, its scoring, the UDS server and the XCP slave iterate the
registry (the servers through the functions' own `dids()` / `variables()`,
vecu.ecu.diagnostics); none of them names a function.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.faults import FaultInjector, FaultTarget
from vecu.plant.drive import Drive
from vecu.probes import Probe
from vecu.stats import ErrorStats


@dataclass(frozen=True)
class EcuInput:
    """One input of an ECU function: the vecu message.signal it becomes, its unit, whether the
    function can run without it (a replay's signal map fills it from a user's DBC)."""

    message: str
    signal: str
    unit: str
    required: bool = True


@dataclass(frozen=True)
class TruthPair:
    """One estimate signal scored against one truth signal (replay scoring)."""

    key: str
    estimate_signal: str
    truth_signal: str
    only_when: tuple[str, int] | None = None  # (signal, value) the estimate frame must carry


@dataclass(frozen=True)
class TruthChannel:
    """A function's estimate message scored against the plant's truth message in a trace."""

    estimate: str   # ECU message
    truth: str      # truth message
    max_age_ns: int
    pairs: tuple[TruthPair, ...]
    burn_in_ns: int = 0
    # the scores in words, `vecu replay`'s line (after "score <function>: ")
    describe: Callable[[Mapping[str, ErrorStats]], str] | None = None
    # (message, signal) of the estimate's validity (vecu.ecu.validity): frames flagged init or
    # invalid are not scored but counted; a message other than `estimate` is sent before it in
    # the same tick (its latest frame at that time counts)
    validity: tuple[str, str] | None = None


@dataclass(frozen=True)
class Sensor:
    """A sensor the function diagnoses (a scenario's per-sensor criteria and monitor keys)."""

    message: str  # the frame that carries it
    monitor: str  # the tree path of its monitor's settings (ecu.*)
    unit: str     # of its series' output and truth
    rank: int = 100  # its place among a scenario's per-sensor criteria


@dataclass(frozen=True)
class Kill:
    """A sensor fault at a time of the run's own options (`vecu run --kill-tps-at`, ...)."""

    task: str  # the scheduler task's name
    at_ns: int
    target: FaultTarget
    kind: str
    value: float | None


Builder = Callable[[RunConfig, DbcCodec, Any], Any]  # -> an EcuFunction
# (config, codec, injector, rngs, drive: the one car's motion every part reads) -> a PlantPart
# (events: the engine-event part)
PartBuilder = Callable[[RunConfig, DbcCodec, FaultInjector, Mapping[str, np.random.Generator],
                        Drive], Any]
ProbeBuilder = Callable[[Any, Any, RunConfig, int], Probe]


@dataclass(frozen=True)
class EcuFunctionSpec:
    """One ECU function as a plug-in.

    enabled(config): whether a run has it (its `RunConfig` switch; its calibration subtree is
    config.params.ecu.<name> for the built-in functions). build(config, codec, seam): the ECU
    function from its calibration; seam: a bench's estimator factory or None. plant_part: the
    plant part that simulates what it estimates (part_name: that part's name), events=True
    when that part runs on the engine-event chain. probe(part, function, config, n_ticks): the
    truth-vs-output probe, whose summary() is the function's typed section of the run summary
    (report_rank orders the sections after the first function's). kill(config): its sensor
    kill of the run's options. sensors: the sensors it diagnoses by short name (its probe's
    series then has output() -> (t, output, truth, source or None)). inputs: the messages it reads (a replay's signal map), truth:
    its replay scoring, estimators: the estimator names its calibration accepts, dbc: DBC files
    with its own messages (beside vecu's), label: what it broadcasts (a replay plot's axis)."""

    name: str
    enabled: Callable[[RunConfig], bool]
    build: Builder
    part_name: str | None = None
    plant_part: PartBuilder | None = None
    events: bool = False
    probe: ProbeBuilder | None = None
    probe_task: str = ""
    kill: Callable[[RunConfig], Kill | None] | None = None
    sensors: Mapping[str, Sensor] = field(default_factory=dict)
    inputs: Mapping[str, EcuInput] = field(default_factory=dict)
    truth: TruthChannel | None = None
    report_rank: int = 100
    plot: Callable[[Any, Any], None] | None = None  # (its series, a matplotlib axes): a panel
    estimators: tuple[str, ...] = ()
    dbc: tuple[str, ...] = ()
    # a plug-in's calibration: the factory of its frozen config dataclass, the subtree
    # ecu.<name>.* of the parameter tree (`vecu params`, --set, XCP, A2L); build() reads it as
    # getattr(config.params.ecu, name)
    params: Callable[[], Any] | None = None
    # DBC files a run's configuration adds (an FMU's databases), beside `dbc`
    run_dbc: Callable[[RunConfig], tuple[str, ...]] | None = None
    label: str = ""  # its broadcast value with unit, a replay plot's axis (default: its name)
    # its hot paths, rows of `vecu bench --only breakdown`: (module, class or None, attribute,
    # row label)
    profile: tuple[tuple[str, str | None, str, str], ...] = ()
