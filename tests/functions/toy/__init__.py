"""A toy fifth ECU function, registered by a test only (vecu.functions.registered): its folder
holds its DBC, plant part, ECU function, probe and registry entry, nothing else. The plant sends
a noisy level every 10 ms; the ECU low-pass filters it and broadcasts the estimate."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.diagnostics import FLOAT, Did, Variable
from vecu.ecu.node import Send, Subscription
from vecu.faults import FaultInjector
from vecu.functions.base import EcuFunctionSpec, EcuInput, TruthChannel, TruthPair
from vecu.plant.drive import Drive
from vecu.stats import ErrorStats, RunningStats

DBC = str(Path(__file__).with_name("toy.dbc"))
PERIOD_NS = 10 * NS_PER_MS
ALPHA = 0.2  # the ECU's low-pass gain
TOY_VERSION = 42  # DID 0x0501: a constant a tester can check


class ToyPart:
    """The plant side: level(t) = 2.5 + sin(pi t) V, plus seeded noise on the sensor."""

    name = "toy"
    period_ns = PERIOD_NS

    def __init__(self, codec: DbcCodec, seed: int) -> None:
        self._sensor, self._truth = codec["TOY_Sensor"], codec["TOY_Truth"]
        self._rng = np.random.default_rng([seed, 1408])
        self.level = 2.5

    def tick(self, t_ns: int, send: Send) -> None:
        t_s = t_ns / NS_PER_S
        self.level = 2.5 + math.sin(math.pi * t_s)
        noisy = min(max(self.level + 0.05 * float(self._rng.standard_normal()), 0.0), 5.0)
        send(self._sensor.frame({"TOY_Level": noisy}, t_s))
        send(self._truth.frame({"TRU_Level": self.level}, t_s))


class ToyFunction:
    """The ECU side: a first-order low-pass of TOY_Level, broadcast as TOY_Estimate."""

    name = "toy"
    period_ns = PERIOD_NS
    timeouts = 0

    def __init__(self, codec: DbcCodec) -> None:
        self._frame = codec["TOY_Estimate"].framer(("TOY_LevelEst",))
        self.estimate: float | None = None
        self._latest: float | None = None
        self.estimates_sent = 0

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("TOY_Sensor", self._on_sensor)]

    def _on_sensor(self, values: dict[str, float], t_ns: int) -> None:
        self._latest = values["TOY_Level"]

    def run(self, t_ns: int, send: Send) -> None:
        if self._latest is None:
            return
        est = self._latest if self.estimate is None else (
            self.estimate + ALPHA * (self._latest - self.estimate))
        self.estimate = est
        self.estimates_sent += send(*self._frame(t_ns / NS_PER_S, est))

    def status_signals(self) -> dict[str, int]:
        return {}

    def dids(self) -> list[Did]:
        return [Did(0x0500, "toy level estimate", "H", 0.001, "V", lambda: self.estimate),
                Did(0x0501, "toy version", "B", 1, "", lambda: float(TOY_VERSION))]

    def variables(self) -> list[Variable]:
        return [Variable("toy.level_v", "V", FLOAT, lambda: self.estimate, 0, 5,
                         "toy level estimate")]


@dataclass(frozen=True)
class ToySummary:
    level_error_v: ErrorStats
    estimates_sent: int

    def lines(self) -> list[str]:
        return [(f"toy: level RMS error {self.level_error_v.rms:.3f} V, "
                f"{self.estimates_sent} estimates")]


class ToyProbe:
    period_ns = PERIOD_NS

    def __init__(self, part: ToyPart, fn: ToyFunction) -> None:
        self.part, self.fn = part, fn
        self.err = RunningStats()

    def tick(self, t_ns: int) -> None:
        if self.fn.estimate is not None:
            self.err.add(self.fn.estimate - self.part.level)

    def series(self) -> None:
        return None

    def summary(self) -> ToySummary:
        return ToySummary(self.err.summary(), self.fn.estimates_sent)


def _part(config: RunConfig, codec: DbcCodec, injector: FaultInjector,
          rngs: Mapping[str, np.random.Generator], drive: Drive) -> ToyPart:
    return ToyPart(codec, config.seed)


SPEC = EcuFunctionSpec(
    name="toy", enabled=lambda config: True,
    build=lambda config, codec, seam: ToyFunction(codec),
    part_name="toy", plant_part=_part,
    probe=lambda part, fn, config, n_ticks: ToyProbe(part, fn), probe_task="toy-probe",
    inputs={"level": EcuInput("TOY_Sensor", "TOY_Level", "V")},
    truth=TruthChannel("TOY_Estimate", "TOY_Truth", PERIOD_NS, (
        TruthPair("level_error_v", "TOY_LevelEst", "TRU_Level"),)),
    report_rank=4, dbc=(DBC,))

