"""The throttle function steps its estimator once per wattmeter sample, also after a stall."""

from __future__ import annotations

from vecu.codec import DbcCodec
from vecu.ecu.throttle_function import MAX_BACKLOG, ThrottleFunction


class SpyEstimator:
    name = "spy"
    resets = 0
    theta_deg = 10.0
    theta_std_deg = 1.0

    def __init__(self) -> None:
        self.steps: list[tuple[float, float | None]] = []

    def step(self, u: float, y: float | None) -> None:
        self.steps.append((u, y))

    def reset(self) -> None:
        pass


def test_one_step_per_sample_with_the_previous_input():
    est = SpyEstimator()
    fn = ThrottleFunction(DbcCodec(), est)
    sent = []
    for k, (u, y) in enumerate([(1.0, 10.0), (2.0, 20.0), (3.0, 30.0)]):  # a 3 ms stall
        fn._on_wattmeter({"ETB_Voltage": u, "ETB_Power": y}, k)
    fn.run(3_000_000, lambda m, values=None: sent.append(m) or True)
    assert est.steps == [(0.0, 10.0), (1.0, 20.0), (2.0, 30.0)]
    fn.run(4_000_000, lambda m, values=None: sent.append(m) or True)  # no sample: predict with the last u
    assert est.steps[-1] == (3.0, None)
    assert len(sent) == 2  # one broadcast per run


def test_backlog_is_bounded_and_counted():
    est = SpyEstimator()
    fn = ThrottleFunction(DbcCodec(), est)
    for k in range(MAX_BACKLOG + 7):
        fn._on_wattmeter({"ETB_Voltage": float(k), "ETB_Power": 1.0}, k)
    fn.run(0, lambda m, values=None: True)
    assert len(est.steps) == MAX_BACKLOG and fn.samples_dropped == 7
    assert est.steps[-1][0] == MAX_BACKLOG + 5  # u of the sample before the newest
