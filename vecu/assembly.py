"""Build the plant and the ECU from a RunConfig, each on its own bus, from the registry of ECU
functions (vecu.functions): used by the in-process run, the separate plant / ECU processes,
trace replay (ECU only) and scenarios.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

from vecu import functions
from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.config import RunConfig, check_ecu_ids
from vecu.ecu.node import EcuFunction, EcuNode
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.registry import make_throttle_estimator
from vecu.estimators.throttle.base import ThrottleEstimator
from vecu.faults import FaultInjector
from vecu.plant.drive import Drive
from vecu.plant.node import PlantNode
from vecu.plant.part import PlantPart
from vecu.rng import rng_streams
from vecu.scheduler import Scheduler

TICK_NS = NS_PER_MS
EstimatorFactory = Callable[..., ThrottleEstimator]
PRIO_PLANT, PRIO_ECU, PRIO_PROBE, PRIO_RECORD = 0, 10, 20, 30


@dataclass(frozen=True)
class EcuFunctions:
    """The ECU's functions by name, in the registry's order (those the configuration has)."""

    by_name: dict[str, EcuFunction]

    @property
    def throttle(self) -> ThrottleFunction:
        """The first function, always there."""
        fn = self.by_name["throttle"]
        assert isinstance(fn, ThrottleFunction)
        return fn

    def get(self, name: str) -> EcuFunction | None:
        return self.by_name.get(name)

    def enabled(self) -> list[EcuFunction]:
        return list(self.by_name.values())


def build_plant(config: RunConfig, codec: DbcCodec, bus: can.BusABC,
                injector: FaultInjector | None = None, truth: bool = False) -> PlantNode:
    """The simulated vehicle with the parts of config's functions (vecu.functions); truth=True
    adds the debug truth frames (dbc/vecu_truth.dbc) so that a recorded trace can be
    scored on its own."""
    rngs = rng_streams(config.seed, ("throttle.input", "throttle.plant", "faults"))
    injector = injector if injector is not None else FaultInjector(rngs["faults"])
    car = config.params.plant
    # one car: every part reads the same drive (vecu.plant.drive, docs/models.md "One car")
    drive = Drive(config.seed, config.speed_manoeuvres, car.sensors.wheel, car.sensors.accel,
                  car.lateral, car.driveline, car.manifold.engine)
    parts: list[PlantPart] = []
    on_events = None
    for spec in functions.enabled(config):
        if spec.plant_part is None:
            continue
        part = spec.plant_part(config, codec, injector, rngs, drive)
        if spec.events:
            on_events = part
        else:
            parts.append(part)
    plant = PlantNode(bus, codec, injector, parts, drive, manifold=on_events)
    if truth:
        plant.enable_truth(codec)
    return plant


def plant_part(plant: PlantNode, name: str | None) -> PlantPart | None:
    """The plant's part called name (None: none)."""
    parts: list[Any] = [*plant.parts, plant.manifold]
    return next((p for p in parts if p is not None and p.name == name), None)


def build_functions(config: RunConfig, codec: DbcCodec,
                    make_estimator: EstimatorFactory = make_throttle_estimator) -> EcuFunctions:
    """The ECU's functions (vecu.functions), each built from its half of the parameter tree (its
    calibration) only; make_estimator(name, noise_scale=..., model=...) builds the throttle
    estimator (a seam for benches). codec: the one of config's ECU instance (vecu.instances)."""
    if codec.instance != config.params.ecu.instance:
        raise ValueError(f"a codec of ECU instance {codec.instance} for a run of instance "
                         f"{config.params.ecu.instance}")
    check_ecu_ids(config.params.ecu, codec)  # the plug-ins' frames too
    seams = {"throttle": make_estimator}
    return EcuFunctions({spec.name: spec.build(config, codec, seams.get(spec.name))
                         for spec in functions.enabled(config)})


def schedule_plant(sched: Scheduler, plant: PlantNode, catch_up_ns: int = 0) -> None:
    """catch_up_ns (live): after a stall, send the missed ticks' frames late within this
    window instead of never (vecu.scheduler)."""
    sched.every(TICK_NS, plant.tick, name="plant", priority=PRIO_PLANT, catch_up_ns=catch_up_ns)
    if plant.manifold is not None:
        sched.chain(0, plant.engine_event, name="engine-events", priority=PRIO_PLANT)


def schedule_ecu(sched: Scheduler, ecu: EcuNode):
    return sched.every(TICK_NS, ecu.tick, name="ecu", priority=PRIO_ECU)
