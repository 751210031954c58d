"""The oil's warm-up law and the function's calibration (ecu.oil_temperature.* in vecu's
parameter tree): T' = (T_hot - T) / tau, a first-order lag towards the running temperature."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

DEGC = {"unit": "degC", "source": "vecu-oil-temperature: a first-order warm-up (its README)"}


@dataclass(frozen=True)
class OilModel:
    """T(t) = hot + (start - hot) exp(-t / tau)."""

    start_degc: float = field(default=20.0, metadata=DEGC)
    hot_degc: float = field(default=95.0, metadata=DEGC)
    tau_s: float = field(default=8.0, metadata={"bounds": (0.1, 1e5),
                                                "source": DEGC["source"]})

    def advance(self, t_degc: float, dt_s: float) -> float:
        """The temperature dt_s later (exact solution of the lag)."""
        return self.hot_degc + (t_degc - self.hot_degc) * math.exp(-dt_s / self.tau_s)


@dataclass(frozen=True)
class OilTemperatureConfig:
    """The ECU's calibration: its copy of the model, the filter's noises, the sensor's range."""

    model: OilModel = field(default_factory=OilModel)
    q_degc2_per_s: float = field(default=0.01, metadata={"unit": "degC^2/s", "bounds": (0, 1e3),
                                                         "source": DEGC["source"]})
    r_degc2: float = field(default=0.25, metadata={"unit": "degC^2", "bounds": (1e-6, 1e3),
                                                   "source": DEGC["source"]})
    low_degc: float = field(default=-40.0, metadata=DEGC)   # a reading outside: refused
    high_degc: float = field(default=180.0, metadata=DEGC)
    timeout_cycles: int = field(default=3, metadata={"bounds": (1, 1000),
                                                     "source": DEGC["source"]})
