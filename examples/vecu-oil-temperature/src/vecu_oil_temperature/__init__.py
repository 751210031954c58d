"""vecu-oil-temperature: an example plug-in ECU function for vecu (docs/plugins.md).

Its entry point (pyproject.toml, group `vecu.functions`) names SPEC below; vecu then runs it in
every command: the plant part simulates the oil and its sensor, the ECU function estimates the
temperature, its calibration is `ecu.oil_temperature.*`, its frames are in oil.dbc.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.faults import FaultInjector
from vecu.functions.base import EcuFunctionSpec, EcuInput, TruthChannel, TruthPair
from vecu.plant.drive import Drive
from vecu.stats import ErrorStats, RunningStats
from vecu_oil_temperature.estimator import PERIOD_NS, OilTemperatureFunction
from vecu_oil_temperature.model import OilModel, OilTemperatureConfig
from vecu_oil_temperature.plant import OilPart

DBC = str(Path(__file__).with_name("oil.dbc"))
NAME = "oil_temperature"


def calibration(config: RunConfig) -> OilTemperatureConfig:
    """The function's subtree of the parameter tree (ecu.oil_temperature)."""
    return getattr(config.params.ecu, NAME)


@dataclass(frozen=True)
class OilSummary:
    """Its section of the run summary (typed; JSON under "oil_temperature")."""

    temp_error_degc: ErrorStats
    estimates_sent: int
    timeouts: int

    def lines(self) -> list[str]:
        e = self.temp_error_degc
        return [(f"oil temperature: estimate RMS error {e.rms:.2f} degC over {e.n} estimates, "
                f"{self.timeouts} sensor timeouts")]


class OilProbe:
    """Estimate against the plant's truth, every 100 ms."""

    period_ns = PERIOD_NS

    def __init__(self, part: OilPart, fn: OilTemperatureFunction) -> None:
        self.part, self.fn = part, fn
        self.err = RunningStats()

    def tick(self, t_ns: int) -> None:
        if self.fn.estimate is not None:
            self.err.add(self.fn.estimate - self.part.temp_degc)

    def series(self) -> None:
        return None

    def summary(self) -> OilSummary:
        return OilSummary(self.err.summary(), self.fn.estimates_sent, self.fn.timeouts)


def _part(config: RunConfig, codec: DbcCodec, injector: FaultInjector,
          rngs: Mapping[str, np.random.Generator], drive: Drive) -> OilPart:
    return OilPart(codec, config.seed, OilModel())  # the truth: the nominal oil


def _build(config: RunConfig, codec: DbcCodec, seam: Any) -> OilTemperatureFunction:
    return OilTemperatureFunction(calibration(config), codec)


SPEC = EcuFunctionSpec(
    name=NAME, enabled=lambda config: True, build=_build,
    part_name="oil_temperature", plant_part=_part,
    probe=lambda part, fn, config, n_ticks: OilProbe(part, fn), probe_task="oil-probe",
    inputs={"oil": EcuInput("OIL_Sensor", "OIL_Temp", "degC")},
    truth=TruthChannel("OIL_Estimate", "OIL_Truth", 100 * NS_PER_MS, (
        TruthPair("temp_error_degc", "OIL_TempEst", "TRU_OilTemp"),),
        validity=("OIL_Estimate", "OIL_Validity")),
    report_rank=10, dbc=(DBC,), params=OilTemperatureConfig, label="oil temperature [degC]")
