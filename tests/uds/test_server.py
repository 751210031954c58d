"""The ECU's UDS server against a real tester (udsoncan's Client over can-isotp) on the
simulated clock, its negative responses, and its robustness under random requests and floods.
Every test here fails on the tree before vecu/uds: a request on 0x7E0 got no answer."""

from __future__ import annotations

import random

import pytest
from udsoncan.exceptions import NegativeResponseException

from tests.uds.sim import SimRun, client_config
from vecu.assembly import TICK_NS
from vecu.clock import NS_PER_MS
from vecu.config import RunConfig
from vecu.ecu.sensor_monitor import SensorStatus
from vecu.faults import FaultTarget
from vecu.uds.security import key_from_seed
from vecu.uds.server import EXTENDED
from vecu.uds.transport import Endpoint, to_can


@pytest.fixture
def sim():
    run = SimRun()
    yield run
    run.close()


@pytest.fixture(scope="module")
def shared():
    """One run for the table of negative responses (each case leaves the default session)."""
    run = SimRun(RunConfig(duration_s=600.0, kill_tps_at_s=None, speed=False, steering=False,
                           manifold=False))
    run.run_to(0.05)
    yield run
    run.close()


def quick(**sets: float) -> SimRun:
    """A throttle-only run with shorter diagnostic timers."""
    return SimRun(RunConfig(duration_s=600.0, kill_tps_at_s=None, speed=False, steering=False,
                            manifold=False).with_params({f"ecu.uds.{k}": v for k, v in sets.items()}))


def test_a_tester_reads_the_vin_the_live_throttle_and_the_tps_dtc_with_its_snapshot(sim):
    sim.run_to(0.3)

    def before(c):
        vin = c.read_data_by_identifier(0xF190).service_data.values[0xF190]
        live = c.read_data_by_identifier([0x0100, 0x0103, 0x0105, 0x0300]).service_data.values
        dtcs = c.get_dtc_by_status_mask(0xFF).service_data.dtcs
        return vin, live, dtcs

    vin, live, dtcs = sim.serve(before)
    thr = sim.fns.throttle
    assert vin == "1VECU00SIM0000001"
    assert abs(live[0x0100] - thr.angle) < 5.0 and live[0x0103] == 0 and live[0x0105] == 0
    assert not [d for d in dtcs if d.status.test_failed or d.status.confirmed]
    sim.kill(FaultTarget.TPS)  # 0 V: open circuit
    sim.step(100)

    def after(c):
        confirmed = c.get_dtc_by_status_mask(0x08).service_data.dtcs
        snap = c.get_dtc_snapshot_by_dtc_number(0x012200, 1).service_data.dtcs[0]
        ext = c.get_dtc_extended_data_by_dtc_number(0x012200, 1).service_data.dtcs[0]
        c.clear_dtc(0xFFFFFF)
        again = c.get_dtc_by_status_mask(0x08).service_data.dtcs
        return confirmed, snap, ext, again

    confirmed, snap, ext, again = sim.serve(after, client_config(dtc_snapshot_did_size=2))
    assert [(d.id, d.status.get_byte_as_int()) for d in confirmed] == [(0x012200, 0x2F)]
    frame = {s.did: s.data for s in snap.snapshots}
    assert frame[0x0104] == 0.0 and frame[0x0105] == SensorStatus.RANGE_LOW  # 0 V, range_low
    assert ext.extended_data[0].raw_data == b"\x01"  # occurrence counter
    assert [d.id for d in again] == [0x012200]  # the fault is still there: back at once
    assert sim.fns.throttle.monitor.dtc_item.confirmations == 2


def test_a_tester_reads_each_estimates_validity_and_sigma_as_the_broadcast_has_them(sim):
    """Issue 30: the validity DIDs 0x0n0F read vecu.ecu.validity's codes, the same state as the
    *_Validity signals; the sigma DIDs the broadcast sigmas."""
    from vecu.ecu.validity import VALID

    sim.run_to(2.0)  # the sigmas settled: they move little while the tester's thread works
    dids = [0x010F, 0x020F, 0x030F, 0x040F, 0x0305, 0x0405, 0x0204]
    got = sim.serve(lambda c: c.read_data_by_identifier(dids).service_data.values)
    fn = sim.fns.by_name
    assert [got[d] for d in dids[:4]] == [fn[n].validity for n in
                                          ("throttle", "manifold", "speed", "steering")]
    assert fn["throttle"].validity == fn["manifold"].validity == VALID
    assert fn["speed"].validity == VALID
    # the DIDs' resolution (0.01) and the ticks the clock ran on after the read
    assert got[0x0305] == pytest.approx(fn["speed"].kf.speed_std_mps * 3.6, abs=0.015)
    assert got[0x0405] == pytest.approx(fn["steering"].swa_std, abs=0.015)
    assert got[0x0405] > 0
    assert got[0x0204] > 0.0


def test_a_tester_unlocks_security_and_forces_a_sensor_value(sim):
    sim.run_to(0.2)
    thr = sim.fns.throttle

    def force(c):
        with pytest.raises(NegativeResponseException) as locked:
            c.io_control(0x0104, control_param=3, values=[0.2])
        c.change_session(3)
        with pytest.raises(NegativeResponseException) as denied:
            c.io_control(0x0104, control_param=3, values=[0.2])
        c.unlock_security_access(1)
        c.io_control(0x0104, control_param=3, values=[0.2])  # 0.2 V: below the open-circuit limit
        return locked.value.response.code, denied.value.response.code

    codes = sim.serve(force, max_sim_s=5.0)
    assert codes == (0x7F, 0x33)  # not in the default session; then securityAccessDenied
    sim.step(20)
    assert thr.monitor.raw == pytest.approx(0.2) and thr.status == SensorStatus.RANGE_LOW
    assert sim.uds.dtcs.records[0x012200].status & 0x09 == 0x09

    def release(c):
        c.tester_present()
        c.io_control(0x0104, control_param=0)  # returnControlToECU

    sim.serve(release, max_sim_s=1.0)
    sim.step(600)  # healed after 500 ms of clean frames
    assert thr.status == SensorStatus.OK and thr.monitor.raw != pytest.approx(0.2)


def _handle(sim, hexes: str, functional: bool = False) -> bytes | None:
    return sim.uds.handle(bytes.fromhex(hexes), functional, sim.t_ns)


def _state(sim) -> tuple:
    u = sim.uds
    return (u.session, u.security.unlocked, dict(u.io), sim.ecu.broadcast_enabled,
            u.dtcs.enabled, {n: r.status for n, r in u.dtcs.records.items()},
            sim.fns.throttle.monitor.cfg)


@pytest.mark.parametrize(("request_hex", "session", "nrc"), [
    ("99", 1, 0x11), ("19 7F", 1, 0x12), ("10 05", 1, 0x12), ("22 F1", 1, 0x13),
    ("3E 00 00", 1, 0x13), ("19 02", 1, 0x13), ("14 FF FF", 1, 0x13), ("10", 1, 0x13),
    ("28 00 01", 1, 0x7F), ("2E 01 10 07 D0", 1, 0x7F), ("27 01", 1, 0x7F),
    ("10 02", 1, 0x7E), ("10 02", 3, 0x22), ("27 02 00 00 00 00", 3, 0x24),
    ("31 03 02 01", 3, 0x24), ("22 12 34", 1, 0x31), ("14 12 34 56", 1, 0x31),
    ("19 04 01 22 00 07", 1, 0x31), ("28 00 00", 3, 0x31), ("31 01 99 99", 3, 0x31),
    ("2E 01 10 07 D0", 3, 0x33), ("2F 01 04 03 07 D0", 3, 0x33),
])
def test_every_bad_request_gets_its_negative_response_and_changes_nothing(shared, request_hex,
                                                                          session, nrc):
    sim = shared
    if session == EXTENDED:
        assert _handle(sim, "10 03")[:2] == b"\x50\x03"
    before = _state(sim)
    assert _handle(sim, request_hex) == bytes([0x7F, int(request_hex[:2], 16), nrc])
    sim.step()
    assert _state(sim) == before
    assert _handle(sim, "10 01")[:2] == b"\x50\x01"


def test_security_access_counts_failed_keys_and_delays_on_the_ecu_clock():
    sim = quick(security_delay_ms=2000.0)
    sim.run_to(0.05)
    _handle(sim, "10 03")
    for expected in (0x35, 0x35, 0x36):
        seed = _handle(sim, "27 01")[2:]
        wrong = bytes(b ^ 0xFF for b in key_from_seed(seed))
        assert _handle(sim, "27 02" + wrong.hex()) == bytes([0x7F, 0x27, expected])
    assert _handle(sim, "27 01") == b"\x7f\x27\x37"  # the delay runs on the ECU's clock
    sim.step(1900)
    assert _handle(sim, "27 01") == b"\x7f\x27\x37"
    sim.step(100)
    seed = _handle(sim, "27 01")[2:]
    assert _handle(sim, "27 02" + key_from_seed(seed).hex()) == b"\x67\x02"
    assert _handle(sim, "27 01") == b"\x67\x01\x00\x00\x00\x00"  # unlocked: the zero seed
    sim.close()


def test_s3_timeout_ends_the_session_and_what_it_enabled():
    sim = quick(s3_ms=1000.0)
    sim.run_to(0.05)
    _handle(sim, "10 03")
    _handle(sim, "27 02" + key_from_seed(_handle(sim, "27 01")[2:]).hex())
    assert _handle(sim, "28 01 01") == b"\x68\x01"  # broadcast off
    assert _handle(sim, "2F 01 04 03 27 10") == b"\x6f\x01\x04\x03\x27\x10"  # TPS 1 V
    sent = sim.fns.throttle.estimates_sent
    sim.step(100)
    assert sim.fns.throttle.estimates_sent == sent and sim.ecu.overrides
    sim.step(900)
    assert sim.uds.session == EXTENDED
    sim.step(100)  # S3: 1 s without a request
    assert sim.uds.session == 1 and not sim.uds.security.unlocked
    assert sim.ecu.broadcast_enabled and not sim.ecu.overrides
    sent = sim.fns.throttle.estimates_sent
    sim.step(10)
    assert sim.fns.throttle.estimates_sent == sent + 10
    sim.close()


def test_functional_requests_are_answered_and_their_unsupported_ones_are_silent(sim):
    sim.run_to(0.05)
    assert _handle(sim, "3E 00", functional=True) == b"\x7e\x00"
    assert _handle(sim, "3E 80", functional=True) is None
    assert _handle(sim, "22 12 34", functional=True) is None  # 0x31 is not sent
    assert _handle(sim, "22 12 34") == b"\x7f\x22\x31"
    assert _handle(sim, "22 F1 90 F1 8C", functional=True)[:3] == b"\x62\xf1\x90"


def _tester(sim):
    bus = sim.bus()
    ep = Endpoint(0x7E8, 0x7E0, lambda: sim.t_ns)
    func = Endpoint(0x7E8, 0x7DF, lambda: sim.t_ns)

    def exchange(requests: list[tuple[bytes, bool]]) -> list[bytes]:
        for payload, functional in requests:
            (func if functional else ep).send(payload, functional=functional)
        for e in (ep, func):
            e.process()
            while e.out:
                bus.send(to_can(e.out.popleft()))
        while (msg := bus.recv(0.0)) is not None:
            if msg.arbitration_id == 0x7E8:
                ep.put(msg)
        ep.process()
        while ep.out:
            bus.send(to_can(ep.out.popleft()))
        return ep.payloads()

    return exchange


SERVICES = [0x10, 0x11, 0x14, 0x19, 0x22, 0x27, 0x2E, 0x2F, 0x31, 0x3E, 0x85, 0x28, 0x23, 0x99]
DIDS = [0xF190, 0xF195, 0xF18C, 0x0100, 0x0104, 0x0110, 0x0300, 0x0403, 0x1234]


def _random_request(rnd: random.Random) -> bytes:
    sid = rnd.choice(SERVICES)
    kind = rnd.random()
    if kind < 0.3:  # a sub-function, maybe suppressed
        body = bytes([rnd.choice([0, 1, 2, 3, 4, 6, 0x0A, 0x7F]) | rnd.choice([0, 0x80])])
    elif kind < 0.6:  # DIDs, DTC numbers, routine IDs
        body = b"".join(rnd.choice(DIDS).to_bytes(2, "big") for _ in range(rnd.randint(0, 3)))
        if sid in (0x19, 0x31):
            body = bytes([rnd.choice([1, 2, 4, 6, 0x0A])]) + body[:4]
    else:  # anything, up to a multi-frame request
        body = rnd.randbytes(rnd.choice([0, 1, 2, 3, 5, 7, 12, 40]))
    if sid == 0x28:  # broadcast off would (rightly) stop the broadcast: keep it on
        body = b"\x00" + body[1:]
    return bytes([sid]) + body


def test_10k_random_requests_in_every_session_keep_the_ecu_answering_and_broadcasting():
    sim = quick()
    sim.run_to(0.02)
    exchange = _tester(sim)
    rnd = random.Random(17)
    thr = sim.fns.throttle
    answers = sessions = direct = 0
    seen_sessions = set()
    for i in range(10_000):
        if i % 500 == 0:  # now and then into the extended session, unlocked (in-process)
            direct += _handle(sim, "10 03") is not None
            seed = _handle(sim, "27 01")
            direct += 1
            if seed[:2] == b"\x67\x01":
                direct += _handle(sim, "27 02" + key_from_seed(seed[2:6]).hex()) is not None
        sent = thr.estimates_sent
        request = _random_request(rnd)
        answers += len(exchange([(request, len(request) <= 7 and rnd.random() < 0.1)]))
        sim.step()
        assert thr.estimates_sent == sent + 1, f"request {i}: a broadcast was missed"
        seen_sessions.add(sim.uds.session)
        sessions += sim.uds.session == EXTENDED
    sim.step(5)
    answers += len(exchange([]))
    stats = sim.uds.stats
    assert stats.requests >= 10_000 and stats.requests_dropped == 0
    assert answers + direct == stats.responses == stats.requests - stats.suppressed
    assert stats.positive > 300 and stats.negative > 8000
    # no request reached a service that raised (the boundary's NRC 0x10 was never needed)
    assert sim.ecu.handler_errors == {}
    assert seen_sessions == {1, 3} and sessions > 500
    got = exchange([(b"\x22\xf1\x90", False)])  # a multi-frame response: FF, FC, CFs
    for _ in range(4):
        sim.step()
        got += exchange([])
    assert got[-1] == b"\x62\xf1\x90" + b"1VECU00SIM0000001"
    sim.close()


def test_a_request_flood_costs_bounded_work_and_no_broadcast(sim):
    sim.run_to(0.02)
    bus = sim.bus()
    thr, cfg = sim.fns.throttle, sim.config.params.ecu.uds
    rnd = random.Random(3)
    for _ in range(200):
        for _ in range(300):  # 300 frames a tick: far beyond what the bus could carry
            data = bytes([rnd.randint(1, 7)]) + rnd.randbytes(7)
            bus.send(to_can_frame(rnd.choice([0x7E0, 0x7DF]), data))
        sent, tx = thr.estimates_sent, sim.ecu.frames_sent
        sim.step()
        assert thr.estimates_sent == sent + 1
        assert sim.ecu.frames_sent - tx <= cfg.frames_per_tick + 8  # + this tick's broadcast
    stats = sim.uds.stats
    assert stats.frames_dropped > 0 and stats.requests > 0
    while bus.recv(0.0) is not None:
        pass
    sim.step(50)  # the backlog drains; then the server answers as before
    assert _handle(sim, "3E 00") == b"\x7e\x00"


def to_can_frame(can_id: int, data: bytes):
    import can

    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


def test_communication_control_stops_and_resumes_every_broadcast(sim):
    sim.run_to(0.05)
    _handle(sim, "10 03")
    tx = sim.ecu.frames_sent
    assert _handle(sim, "28 01 01") == b"\x68\x01"
    sim.step(200)
    assert sim.ecu.frames_sent == tx  # estimates, ECU_Status, ECU_Diag: all muted
    assert _handle(sim, "28 00 03") == b"\x68\x00"
    sim.step(10)
    assert sim.ecu.frames_sent > tx + 10
    assert TICK_NS == NS_PER_MS


def test_return_control_to_the_ecu_answers_with_the_sensors_own_value(sim):
    """2F .. 00 (returnControlToECU) carries the value the ECU sees again: the sensor's own,
    not the forced one (it answered 0.2 V, the override, before issue 29)."""
    sim.run_to(0.2)
    _handle(sim, "10 03")
    _handle(sim, "27 02" + key_from_seed(_handle(sim, "27 01")[2:]).hex())
    assert _handle(sim, "2F 01 04 03 07 D0") == bytes.fromhex("6F 01 04 03 07 D0")  # 0.2 V
    sim.step(20)
    mon = sim.fns.throttle.monitor
    assert mon.raw == pytest.approx(0.2)
    own = sim.ecu.own_value("TPS_Sensor", "TPS_Voltage")
    assert own is not None and own > 0.5  # the plant's sensor, far from the forced 0.2 V
    response = _handle(sim, "2F 01 04 00")
    assert response[:4] == bytes.fromhex("6F 01 04 00")
    assert int.from_bytes(response[4:6], "big") == round(own / 0.0001)
    sim.step(2)
    assert abs(mon.raw - own) < 0.3  # what the ECU sees from the next frame on (it moves)


def test_uds_latency_counts_the_ticks_a_request_waited_in_the_inbox(sim):
    """latency_max_ms: request's last frame taken from the bus -> response, on the ECU's clock.
    A request behind 100 frames is taken from the bus in the second tick (the ECU takes 64 a
    tick: ecu.rx.frames_per_tick) and then waits in the inbox (32 frames a tick); when it was
    stamped at reassembly instead, it read 0.0 whatever the wait."""
    sim.run_to(0.02)
    bus = sim.bus()
    assert sim.uds.stats.latency_max_ms == 0.0
    _handle(sim, "10 01")
    sim.step()
    assert sim.uds.stats.latency_max_ms == 0.0  # handled directly: no wait
    for _ in range(100):  # flow controls with no transfer of the ECU's: inbox work, no request
        bus.send(to_can_frame(0x7E0, bytes.fromhex("30 00 00 CC CC CC CC CC")))
    bus.send(to_can_frame(0x7E0, bytes.fromhex("03 22 F1 86 CC CC CC CC")))
    t0 = sim.t_ns
    answered = None
    for _ in range(20):
        sim.step()
        while (msg := bus.recv(0.0)) is not None:
            if msg.arbitration_id == 0x7E8 and answered is None:
                answered = sim.t_ns
        if answered is not None:
            break
    assert answered is not None
    taken = -(-101 // sim.ecu.rx_budget.frames_per_tick)  # the tick that takes the request in
    waited_ms = (answered - t0) / NS_PER_MS - taken
    assert waited_ms >= 2
    assert sim.uds.stats.latency_max_ms == pytest.approx(waited_ms)


def test_a_dtc_snapshot_says_what_the_host_did_to_the_ecu_and_to_the_sensors_sender(sim):
    """Issue 29 item 2: a live plant reports the ticks its host skipped or delayed in PLANT_Host
    frames; the ECU keeps the latest, and a DTC's snapshot carries them (0x0003 / 0x0004) with
    the ECU's own time not running (0x0002): a stalled host tells itself from a dead sensor."""
    sim.run_to(0.05)
    bus = sim.bus()
    report = sim.codec["PLANT_Host"]
    bus.send(report.frame({"PH_SkippedSends": 2639, "PH_LateSends": 17, "PH_MaxLateness": 50.6,
                           "PH_Counter": 1}, 0.05))
    sim.step(2)
    assert (sim.ecu.host.sender_skipped, sim.ecu.host.sender_late) == (2639, 17)
    sim.kill(FaultTarget.TPS)
    sim.step(100)
    response = _handle(sim, "19 04 01 22 00 01")
    assert response[:6] == bytes.fromhex("59 04 01 22 00 2F") or response[:5] == bytes.fromhex(
        "59 04 01 22 00")
    snapshot = response[8:]
    assert bytes.fromhex("0002 00000000") in snapshot  # the simulated ECU never stalls
    assert bytes.fromhex("0003") + (2639).to_bytes(2, "big") in snapshot
    assert bytes.fromhex("0004") + (17).to_bytes(2, "big") in snapshot
