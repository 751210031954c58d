"""Testing against vecu from pytest (docs/python.md): vecu.simulate for a whole run on the
simulated clock, and the fixtures of vecu's pytest plugin (installed with vecu) for plant + ECU
live on a private bus with a UDS tester connected to it."""

from __future__ import annotations

import udsoncan

import vecu
from vecu.codec import shared_codec


def test_a_dead_tps_is_detected_and_the_estimate_takes_over():
    summary = vecu.simulate(duration_s=1.0, seed=7)  # the TPS dies at half the duration
    detection = summary.throttle.detection
    assert detection.kill_time_s == 0.5 and detection.detected
    assert detection.detection_latency_ms < 100
    assert summary.throttle.final_source == "estimate"


def test_the_ecu_broadcasts_and_answers_a_tester(vecu_rig, vecu_tester):
    # vecu_tester started the rig (plant + ECU on the wall clock, 5 s) and connected to its UDS
    vecu_tester.config["data_identifiers"] = {0xF190: udsoncan.AsciiCodec(17)}
    response = vecu_tester.read_data_by_identifier(0xF190)
    assert response.service_data.values[0xF190] == vecu_rig.config.params.ecu.uds.vin

    estimate = shared_codec()["ECU_ThrottleEstimate"]
    bus = vecu_rig.bus()
    angles = []
    while len(angles) < 20:
        msg = bus.recv(timeout=1.0)
        assert msg is not None, "the ECU went quiet"
        if msg.arbitration_id == estimate.frame_id:
            angles.append(estimate.decode(msg.data)["THR_Angle"])
    assert all(-10 <= a <= 100 for a in angles)
