"""Every restbus disturbance seen as the intended failure: by an independent checker (autosar-e2e's
check, an alive-counter check, the frame times and lengths) on a user's DBC, and by vecu's own ECU
on vecu's own frames (P11); each start and end recorded as an FI_Event frame."""

from __future__ import annotations

from itertools import pairwise

import e2e as autosar_e2e
import numpy as np
import pytest

from tests.restbus.test_restbus import collect
from vecu.bus import SinkBus
from vecu.clock import SimClock
from vecu.codec import DbcCodec, builtin_dbc_path, shared_codec
from vecu.e2e import AliveCounterCheck
from vecu.ecu.node import EcuNode
from vecu.ecu.throttle_function import ThrottleFunction
from vecu.estimators.throttle.ukf_fast import FastThrottleUKF
from vecu.restbus import disturb
from vecu.restbus.commands import bits_value, command_frame, value_bits
from vecu.restbus.node import RestbusNode
from vecu.restbus.spec import RestbusConfig, build_plans
from vecu.scheduler import Scheduler

MSG = "BREMSE_33"  # abs.dbc, 0x343, 10 ms
NS_PER_MS = 1_000_000


@pytest.fixture
def abs_cfg(tmp_path, thirdparty):
    e2e_file = tmp_path / "E2E.toml"
    e2e_file.write_text(f'[[e2e]]\nmessage = "{MSG}"\nprofile = "P05"\ndata_id = 0x0343\n')
    return RestbusConfig((str(thirdparty / "dbc" / "abs.dbc"),), e2e_path=str(e2e_file))


def verdicts(plans, frames):
    """Per frame of MSG: (t_ms, length, crc ok, counter ok) from the independent checkers."""
    plan = next(p for p in plans if p.name == MSG)
    counter = AliveCounterCheck(plan.e2e.counter_modulo)
    out = []
    for m in frames:
        if m.arbitration_id != plan.codec.frame_id:
            continue
        data = bytearray(m.data)
        crc = len(data) == 8 and autosar_e2e.p05.e2e_p05_check(data, 0x0343)
        cnt = counter.check(plan.e2e.counter(data)) if len(data) >= 3 else False
        out.append((round(m.timestamp * 1000), len(data), crc, cnt))
    return out


# kind -> (value, what the independent checker must see between 1 s and 2 s, and not before)
EXPECT = {
    "counter_freeze": (None, lambda v: sum(not c for _, _, _, c in v) >= 90),
    "counter_skip": (2, lambda v: all(not c for _, _, _, c in v[1:])),
    "counter_repeat": (1, lambda v: sum(not c for _, _, _, c in v) == 50),
    "counter_offset": (5, lambda v: sum(not c for _, _, _, c in v) == 1),
    "counter_random": (None, lambda v: sum(not c for _, _, _, c in v) >= 80),
    "crc_wrong": (None, lambda v: not any(ok for _, _, ok, _ in v)),
    "crc_fixed": (0x1234, lambda v: sum(ok for _, _, ok, _ in v) <= 1),
    "drop": (5, lambda v: len(v) == 95),
    "stop": (None, lambda v: v == []),
    "delay": (3, lambda v: all(t % 10 == 3 for t, *_ in v)),
    "cycle": (2.5, lambda v: len(v) == 40 and {b[0] - a[0] for a, b in pairwise(v)} == {25}),
    "dlc": (4, lambda v: all(n == 4 and not ok for _, n, ok, _ in v)),
    "corrupt": (3, lambda v: len(v) == 100 and not any(ok for _, _, ok, _ in v)),
}


def test_every_kind_is_registered_with_its_own_fi_event_code():
    codes = [k.code for k in disturb.KINDS.values()]
    assert len(set(codes)) == len(codes) and min(codes) > 16 and max(codes) <= 31
    assert set(disturb.KINDS) == set(EXPECT) | {"override"}
    text = builtin_dbc_path().read_text()
    table = next(ln for ln in text.splitlines() if ln.startswith("VAL_ 1777 FI_EvKind"))
    for name, k in disturb.KINDS.items():  # the DBC's FI_EvKind table names each code
        assert f' {k.code} "' in table and name.split("_")[-1] in table, name


@pytest.mark.parametrize("kind", sorted(EXPECT))
def test_each_disturbance_is_the_intended_check_failure(kind, abs_cfg):
    value, seen = EXPECT[kind]
    plans, node, frames = collect(abs_cfg, 3.0, [(1.0, MSG, kind, value, 2.0)])
    v = verdicts(plans, frames)
    before = [x for x in v if x[0] < 1000]
    during = [x for x in v if 1000 <= x[0] < 2000]
    after = [x for x in v if x[0] >= 2100]
    assert len(before) == 100 and all(ok and c for _, _, ok, c in before[1:]), kind
    assert seen(during), (kind, during[:5])
    assert after and all(ok for _, _, ok, _ in after), kind  # healthy again after the end
    ev = [(e.kind, e.active) for e in node.events]
    assert ev[0] == (kind, True) and (kind, False) in ev


def test_signal_override_is_seen_in_the_decoded_signal(abs_cfg):
    plans, _, frames = collect(abs_cfg, 2.0, [(0.5, f"{MSG}.whlspeed_RR", "override", 42.0,
                                                  1.5)])
    plan = next(p for p in plans if p.name == MSG)
    got = [(round(m.timestamp * 1000), plan.codec.decode(m.data)["whlspeed_RR"])
           for m in frames if m.arbitration_id == plan.codec.frame_id]
    assert all(v == 42.0 for t, v in got if 500 <= t < 1500)
    assert all(v != 42.0 for t, v in got if t < 500 or t >= 1500)


def test_bad_disturbances_are_refused_naming_the_problem(abs_cfg):
    plans, _, _ = build_plans(abs_cfg)
    node = RestbusNode(plans, lambda m: True, np.random.default_rng(0))
    with pytest.raises(ValueError, match="unknown restbus disturbance 'melt'"):
        node.check(MSG, "melt")
    with pytest.raises(ValueError, match="has no E2E protection"):
        node.check("BREMSE_10", "crc_wrong")
    with pytest.raises(ValueError, match="needs MESSAGE.SIGNAL"):
        node.check(MSG, "override", 1.0)
    with pytest.raises(ValueError, match="has no signal 'nope'"):
        node.check(f"{MSG}.nope", "override", 1.0)
    with pytest.raises(ValueError, match=r"must be in \[0, 64\]"):
        node.check(MSG, "dlc", 65)


def test_disturbances_go_on_the_bus_as_fi_event_frames(abs_cfg):
    plans, _, _ = build_plans(abs_cfg)
    frames = []
    fi = shared_codec()["FI_Event"]
    node = RestbusNode(plans, lambda m: frames.append(m) or True, np.random.default_rng(0), fi)
    node.disturb(5_000_000, MSG, "crc_fixed", 7.0, source="scenario")
    node.clear(9_000_000, MSG, source="scenario")
    events = [fi.decode(m.data) for m in frames if m.arbitration_id == fi.frame_id]
    assert [(e["FI_EvKind"], e["FI_EvActive"], e["FI_EvMessageId"], e["FI_EvValue"],
             e["FI_EvSource"]) for e in events] == [
        (23, 1, 0x343, 7.0, 1), (23, 0, 0x343, 7.0, 1)]


def test_rb_command_value_bits_keep_four_digits_and_round_trip():
    for v in (0.0, 1.0, 2.5, -3.25, 42.0, 1234.5, 0.001, 1e6, -7e-5):
        assert bits_value(value_bits(v)) == pytest.approx(v, rel=3e-4)
    msg = command_frame(0x343, False, 4, "override", True, 42.0)
    assert msg.arbitration_id == 0x6F2 and len(msg.data) == 8


# ---------------------------------------------------------------- vecu's ECU on its own frames
ECU_EXPECT = {"counter_freeze": "counter_errors", "counter_skip": "counter_errors",
              "counter_repeat": "counter_errors", "counter_offset": "counter_errors",
              "counter_random": "counter_errors", "crc_wrong": "crc_errors",
              "crc_fixed": "crc_errors", "dlc": "dlc_errors"}


@pytest.mark.parametrize("kind", sorted(ECU_EXPECT))
def test_vecus_ecu_sees_each_e2e_disturbance_of_a_restbus_tps(kind):
    """The TPS frames from a restbus of vecu's own DBC (node PLANT, P11 from its layout) into
    the ECU's receive path: healthy frames pass, the disturbed ones land in the intended
    counter."""
    cfg = RestbusConfig((str(builtin_dbc_path()),), nodes=("PLANT",), default_cycle_ms=1.0)
    plans, _, _ = build_plans(cfg)
    plans = [p for p in plans if p.name == "TPS_Sensor"]
    assert plans[0].e2e is not None and plans[0].e2e.profile == "P11"
    codec = DbcCodec()
    ecu = EcuNode(SinkBus(), codec, [ThrottleFunction(codec, FastThrottleUKF("arm"))])
    sched = Scheduler(SimClock())
    node = RestbusNode(plans, lambda m: ecu.receive(m, round(m.timestamp * 1e9)) or True,
                       np.random.default_rng(2))
    node.schedule(sched)
    value = {"counter_skip": 2, "counter_offset": 5, "dlc": 3, "crc_fixed": 0}.get(kind)
    sched.at(200 * NS_PER_MS, lambda t: node.disturb(t, "TPS_Sensor", kind, value), name="d")
    sched.run_until(200 * NS_PER_MS)
    rx = ecu.rx
    assert rx.received == 200 and rx.crc_errors == rx.counter_errors == rx.dlc_errors == 0
    sched.run_until(300 * NS_PER_MS)
    assert getattr(rx, ECU_EXPECT[kind]) >= (1 if kind == "counter_offset" else 30), (
        kind, rx.as_dict())

