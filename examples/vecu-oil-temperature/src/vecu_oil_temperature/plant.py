"""The plant side: the oil warms up (model.OilModel, the truth) and a noisy sensor reads it every
100 ms; the truth goes out as OIL_Truth for scoring."""

from __future__ import annotations

import numpy as np

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.ecu.node import Send
from vecu_oil_temperature.model import OilModel

PERIOD_NS = 100 * NS_PER_MS
SENSOR_SD_DEGC = 0.5


class OilPart:
    """A vecu plant part: name, period_ns, tick(t_ns, send), truth_message."""

    name = "oil_temperature"
    period_ns = PERIOD_NS
    truth_message = "OIL_Truth"

    def __init__(self, codec: DbcCodec, seed: int, model: OilModel) -> None:
        self._sensor, self._truth = codec["OIL_Sensor"], codec["OIL_Truth"]
        self._rng = np.random.default_rng([seed, 1440])  # its own seeded stream
        self.model = model
        self.temp_degc = model.start_degc
        self._t_ns = 0

    def tick(self, t_ns: int, send: Send) -> None:
        self.temp_degc = self.model.advance(self.temp_degc, (t_ns - self._t_ns) / NS_PER_S)
        self._t_ns = t_ns
        t_s = t_ns / NS_PER_S
        reading = self.temp_degc + SENSOR_SD_DEGC * float(self._rng.standard_normal())
        send(self._sensor.frame({"OIL_Temp": reading}, t_s))
        send(self._truth.frame({"TRU_OilTemp": self.temp_degc}, t_s))
