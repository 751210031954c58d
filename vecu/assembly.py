"""Build the plant and the ECU from a RunConfig, each on its own bus.

One place that knows which parts and functions exist, used by the in-process run, the separate
plant / ECU processes, trace replay (ECU only) and scenarios.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import can

from vecu.clock import NS_PER_MS
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.manifold_function import ManifoldFunction
from vecu.ecu.node import EcuFunction, EcuNode
from vecu.ecu.speed_function import SpeedFunction
from vecu.ecu.steering_function import SteeringFunction
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.registry import make_throttle_estimator
from vecu.estimators.throttle.base import ThrottleEstimator
from vecu.faults import FaultInjector
from vecu.plant.drive import Drive
from vecu.plant.input_file import FileInput, load_input_file
from vecu.plant.node import (
    LateralPart,
    LongitudinalPart,
    ManifoldPart,
    PlantNode,
    PlantPart,
    ThrottlePart,
)
from vecu.plant.throttle import (
    InputGenerator,
    ThrottlePlant,
)
from vecu.rng import rng_streams
from vecu.scheduler import Scheduler

TICK_NS = NS_PER_MS
EstimatorFactory = Callable[..., ThrottleEstimator]
PRIO_PLANT, PRIO_ECU, PRIO_PROBE, PRIO_RECORD = 0, 10, 20, 30


@dataclass(frozen=True)
class EcuFunctions:
    """The ECU's functions by name (None where the configuration leaves one out)."""

    throttle: ThrottleFunction
    speed: SpeedFunction | None
    steering: SteeringFunction | None
    manifold: ManifoldFunction | None

    def enabled(self) -> list[EcuFunction]:
        return [f for f in (self.throttle, self.speed, self.steering, self.manifold)
                if f is not None]


def build_plant(config: RunConfig, codec: DbcCodec, bus: can.BusABC,
                injector: FaultInjector | None = None, truth: bool = False) -> PlantNode:
    """The simulated vehicle with the parts config asks for; truth=True adds the debug truth
    frames (vecu/dbc/vecu_truth.dbc) so that a recorded trace can be scored on its own."""
    car = config.params.plant
    rngs = rng_streams(config.seed, ("throttle.input", "throttle.plant", "faults"))
    injector = injector if injector is not None else FaultInjector(rngs["faults"])
    inputs: InputGenerator | FileInput = (  # the §III-B excitation, or a user's u(t) file
        InputGenerator(car.input, rngs["throttle.input"]) if config.throttle_input is None
        else FileInput(load_input_file(config.throttle_input)))
    parts: list[PlantPart] = [ThrottlePart(
        codec, ThrottlePlant(car.throttle, rngs["throttle.plant"]), inputs, injector,
        car.sensors.tps)]
    # one car: every part reads the same drive (vecu.plant.drive, docs/models.md "One car")
    drive = Drive(config.seed, config.speed_manoeuvres, car.sensors.wheel, car.sensors.accel,
                  car.lateral, car.driveline, car.manifold.engine)
    if config.speed:
        parts.append(LongitudinalPart(codec, config.seed, drive=drive))
    if config.steering:
        parts.append(LateralPart(codec, drive, config.seed, injector, car.lateral,
                                 car.sensors.lateral))
    plant = PlantNode(bus, codec, injector, parts)
    plant.drive = drive
    if config.manifold:
        plant.manifold = ManifoldPart(codec, config.seed, car.manifold, drive)
    if truth:
        plant.enable_truth(codec)
    return plant


def build_functions(config: RunConfig, codec: DbcCodec,
                    make_estimator: EstimatorFactory = make_throttle_estimator) -> EcuFunctions:
    """The ECU's functions, built from its half of the parameter tree (its calibration) only;
    make_estimator(name, noise_scale=..., model=...) builds the throttle estimator (a seam for
    benches); model is the ECU's throttle calibration `ecu.throttle.model`."""
    cal = config.params.ecu
    estimator = make_estimator(cal.throttle.estimator, noise_scale=cal.throttle.noise_scale,
                               model=cal.throttle.model)
    return EcuFunctions(
        throttle=ThrottleFunction(codec, estimator, cal.throttle),
        speed=SpeedFunction(codec, config=cal.speed) if config.speed else None,
        steering=SteeringFunction(codec, cal.steering) if config.steering else None,
        manifold=ManifoldFunction(codec, cal.manifold) if config.manifold else None)


def schedule_plant(sched: Scheduler, plant: PlantNode, catch_up_ns: int = 0) -> None:
    """catch_up_ns (live): after a stall, send the missed ticks' frames late within this
    window instead of never (vecu.scheduler)."""
    sched.every(TICK_NS, plant.tick, name="plant", priority=PRIO_PLANT, catch_up_ns=catch_up_ns)
    if plant.manifold is not None:
        sched.chain(0, plant.engine_event, name="engine-events", priority=PRIO_PLANT)


def schedule_ecu(sched: Scheduler, ecu: EcuNode):
    return sched.every(TICK_NS, ecu.tick, name="ecu", priority=PRIO_ECU)
