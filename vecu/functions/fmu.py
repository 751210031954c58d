"""A user's FMU as an ECU function (vecu.fmu): on when the run's configuration has one
(`--fmu MODEL.fmu --fmu-map MAP.toml`, a scenario's [fmu] table; RunConfig.with_fmu)."""

from __future__ import annotations

from typing import Any

from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.fmu.function import FmuFunction, FmuSummary
from vecu.functions.base import EcuFunctionSpec


def _build(config: RunConfig, codec: DbcCodec, seam: Any) -> FmuFunction:
    assert config.fmu is not None  # enabled() says so
    return FmuFunction(config.fmu, getattr(config.params.ecu.fmu, config.fmu.name), codec)


class FmuProbe:
    """The FMU function's summary section (no plant part: nothing to compare with)."""

    def __init__(self, fn: FmuFunction) -> None:
        self.fn = fn
        self.period_ns = fn.binding.step_ms * NS_PER_MS

    def tick(self, t_ns: int) -> None:
        pass

    def series(self) -> None:
        return None

    def summary(self) -> FmuSummary:
        return self.fn.summary()


def _run_dbc(config: RunConfig) -> tuple[str, ...]:
    return () if config.fmu is None else config.fmu.dbcs


SPEC = EcuFunctionSpec(
    name="fmu", enabled=lambda config: config.fmu is not None, build=_build,
    probe=lambda part, fn, config, n_ticks: FmuProbe(fn), probe_task="fmu-probe",
    report_rank=50, run_dbc=_run_dbc, label="FMU outputs")
