"""Restbus from the user's databases: every third-party DBC as a restbus (each message with a
cycle time at exactly its period on the simulated clock), send types, start values,
multiplexing, extended IDs and CAN FD, E2E per E2E.toml checked by autosar-e2e, determinism."""

from __future__ import annotations

from pathlib import Path

import cantools
import e2e as autosar_e2e
import numpy as np
import pytest
from can.util import CAN_FD_DLC, dlc2len, len2dlc

from vecu.cli import build_parser, run_command
from vecu.clock import SimClock
from vecu.e2e import AliveCounterCheck
from vecu.errors import BadFileError
from vecu.restbus.node import RestbusNode
from vecu.restbus.session import RestbusRun, run_restbus
from vecu.restbus.spec import TOO_LONG, RestbusConfig, build_plans
from vecu.scheduler import Scheduler

NS_PER_MS = 1_000_000


def collect(cfg: RestbusConfig, duration_s: float, disturbances=()):
    """Run the restbus of cfg on the simulated clock; (plans, node, frames sent)."""
    plans, _, _ = build_plans(cfg)
    frames = []

    def send(msg):
        frames.append(msg)
        return True

    sched = Scheduler(SimClock())
    node = RestbusNode(plans, send, np.random.default_rng(cfg.seed), keep_times=True)
    node.schedule(sched)
    for t, target, kind, value, end in disturbances:
        sched.at(round(t * 1e9), lambda tn, a=(target, kind, value): node.disturb(tn, *a),
                 name="d")
        if end is not None:
            sched.at(round(end * 1e9), lambda tn, a=(target, kind): node.clear(tn, *a), name="e")
    sched.run_until(round(duration_s * 1e9))
    return plans, node, frames


def dbcs(thirdparty: Path) -> list[Path]:
    return sorted((thirdparty / "dbc").glob("*.dbc"))


def test_every_thirdparty_dbc_is_a_restbus_with_exact_periods(thirdparty):
    ran = refused = 0
    for path in dbcs(thirdparty):
        cfg = RestbusConfig((str(path),))
        try:
            plans, node, frames = collect(cfg, 2.0)
        except BadFileError as exc:  # the one-line error: no message has a cycle time
            assert "has a cycle time" in str(exc) and str(path) in str(exc)
            refused += 1
            plans, node, frames = collect(RestbusConfig((str(path),), default_cycle_ms=25.0),
                                          2.0)
        ran += 1
        assert frames, path.name
        for plan, st in zip(plans, node.states):
            fc = plan.codec
            times = st.times_ns
            if plan.send_type == "cyclic":
                assert times[0] == 0 and len(times) == 2000 * NS_PER_MS // plan.period_ns, (
                    path.name, fc.name)
                assert set(np.diff(times)) == {plan.period_ns}, (path.name, fc.name)
                want = (fc.cycle_time_ms or 25.0) * NS_PER_MS
                assert plan.period_ns == round(want)
            elif plan.send_type == "on_change":  # constant start values: once, at the start
                assert times == [0], (path.name, fc.name)
        db = cantools.database.load_file(str(path), strict=False)
        for msg in frames:  # frame format and length as the database says; payload decodes
            plan = next(p for p in plans if p.codec.frame_id == msg.arbitration_id
                        and p.codec.is_extended == msg.is_extended_id)
            assert msg.is_fd == plan.codec.is_fd
            # a frame the bus can carry (no byte beyond it lost), the database's length or the
            # next valid CAN FD length; cantools, reading the file itself, decodes every signal
            assert len(msg.data) in (CAN_FD_DLC if msg.is_fd else range(9)), (path.name, msg)
            assert len(msg.data) == dlc2len(len2dlc(plan.codec.length)), (path.name, msg)
            decoded = db.decode_message(msg.arbitration_id, msg.data, decode_choices=False,
                                        force_extended_id=msg.is_extended_id)
            spec = db.get_message_by_frame_id(msg.arbitration_id
                                              | (0x80000000 if msg.is_extended_id else 0))
            assert (decoded if spec.is_multiplexed() else set(decoded) == {
                s.name for s in spec.signals}), (path.name, plan.name)
    assert ran == len(dbcs(thirdparty)) and 0 < refused < ran


def test_a_message_longer_than_its_frame_is_refused_and_counted(thirdparty, capsys):
    """variable_dlc.dbc's TestMessage2 has 10 bytes on a classic frame: never sent truncated
    (its last signal lost), but named on `vecu restbus`'s one line and counted in the summary."""
    path = str(thirdparty / "dbc" / "variable_dlc.dbc")
    result = run_restbus(RestbusRun(RestbusConfig((path,), default_cycle_ms=10.0),
                                    duration_s=0.1))
    s = result.summary
    assert s["refused_too_long"] == ["TestMessage2"]
    assert s["skipped"]["TestMessage2"].startswith(TOO_LONG)
    assert "10 bytes, a classic CAN frame carries 8" in s["skipped"]["TestMessage2"]
    assert s["per_message"] == {"TestMessage1": 10} and s["encode_errors"] == 0
    assert run_command(build_parser().parse_args(
        ["restbus", path, "--default-cycle", "10", "--duration", "0.1"])) == 0
    out = capsys.readouterr()
    assert out.out.count("TestMessage2") == 1 and not out.err
    assert "not sent: 1 (too long for its frame: 10 bytes" in out.out


def test_a_long_message_marked_can_fd_goes_out_as_can_fd(tmp_path):
    """The same 10 bytes where the database says CAN FD: sent, padded to 12 (a valid FD length)."""
    dbc = tmp_path / "fd10.dbc"
    dbc.write_text(FD10_DBC)
    _, node, frames = collect(RestbusConfig((str(dbc),), default_cycle_ms=10.0), 0.05)
    assert frames and all(m.is_fd and len(m.data) == 12 for m in frames)
    db = cantools.database.load_file(str(dbc))
    assert db.decode_message(0x123, frames[0].data)["Last"] == 5


def test_multiplexed_messages_cycle_through_every_multiplexer_selection(thirdparty):
    path = thirdparty / "dbc" / "multiplex_2.dbc"
    plans, _, frames = collect(RestbusConfig((str(path),), default_cycle_ms=10.0), 1.0)
    for plan in plans:
        fc = plan.codec
        sels = fc.mux_selections
        got = [fc.decode(m.data) for m in frames if m.arbitration_id == fc.frame_id]
        for k, values in enumerate(got[:3 * len(sels)]):
            want = sels[k % len(sels)]
            assert {n: values[n] for n in want} == want, (fc.name, k)


def test_extended_ids_and_can_fd_go_out_as_the_database_says(thirdparty):
    path = thirdparty / "dbc" / "fd_test.dbc"
    plans, _, frames = collect(RestbusConfig((str(path),), default_cycle_ms=10.0), 0.1)
    kinds = {(m.is_extended_id, m.is_fd) for m in frames}
    assert kinds == {(p.codec.is_extended, p.codec.is_fd) for p in plans}
    assert len(kinds) >= 3


def test_start_values_are_the_databases(thirdparty):
    path = thirdparty / "dbc" / "vehicle.dbc"
    plans, _, frames = collect(RestbusConfig((str(path),), default_cycle_ms=100.0), 0.1)
    by_id = {m.arbitration_id: m for m in frames}
    checked = 0
    for plan in plans:
        values = plan.codec.decode(by_id[plan.codec.frame_id].data)
        for name, start in plan.codec.start_values.items():
            lo, hi = plan.codec.ranges[name]
            if (lo is None or start >= lo) and (hi is None or start <= hi):
                assert values[name] == pytest.approx(start, abs=abs(
                    plan.codec.signal(name).scale)), (plan.name, name)
                checked += 1
    assert checked > 400
    assert any(v for p in plans for v in p.codec.start_values.values())  # not all zero


def test_nodes_choose_the_messages_and_an_unknown_node_is_named(thirdparty):
    path = str(thirdparty / "dbc" / "foobar.dbc")
    plans, _, _ = build_plans(RestbusConfig((path,), nodes=("FOO",)))
    assert plans and all("FOO" in p.codec.senders for p in plans)
    with pytest.raises(Exception, match="--node NOPE: no such sending node"):
        build_plans(RestbusConfig((path,), nodes=("NOPE",)))


def test_send_types_cyclic_on_change_and_if_active(tmp_path, thirdparty):
    dbc = tmp_path / "types.dbc"
    dbc.write_text(SEND_TYPES_DBC)
    values = tmp_path / "values.toml"
    values.write_text('[[value]]\nsignal = "Chg.C"\nkind = "square"\nlow = 0\nhigh = 5\n'
                      'period_s = 0.2\n'
                      '[[value]]\nsignal = "Act.A"\nkind = "square"\nlow = 0\nhigh = 3\n'
                      'period_s = 0.5\nduty = 0.4\n')
    plans, node, _ = collect(RestbusConfig((str(dbc),), values_path=str(values)), 1.0)
    sent = {p.name: st.times_ns for p, st in zip(plans, node.states)}
    types = {p.name: p.send_type for p in plans}
    assert types == {"Cyc": "cyclic", "Chg": "on_change", "Act": "if_active"}
    assert len(sent["Cyc"]) == 50
    # on change: polled at its 10 ms cycle, sent when the square wave flips (every 0.1 s)
    assert sent["Chg"] == [k * 100 * NS_PER_MS for k in range(10)]
    # if active: every 20 ms while A != its start value 0 (the first 0.2 s of each 0.5 s)
    assert sent["Act"] and all((t % (500 * NS_PER_MS)) < 200 * NS_PER_MS for t in sent["Act"])
    assert len(sent["Act"]) == 20


SEND_TYPES_DBC = '''VERSION ""
NS_ :
BS_:
BU_: N
BO_ 16 Cyc: 2 N
 SG_ X : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BO_ 17 Chg: 2 N
 SG_ C : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BO_ 18 Act: 2 N
 SG_ A : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ BO_ "GenMsgSendType" ENUM "Cyclic","OnChange","IfActive";
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_DEF_DEF_ "GenMsgSendType" "Cyclic";
BA_ "GenMsgCycleTime" BO_ 16 20;
BA_ "GenMsgCycleTime" BO_ 17 10;
BA_ "GenMsgCycleTime" BO_ 18 20;
BA_ "GenMsgSendType" BO_ 17 1;
BA_ "GenMsgSendType" BO_ 18 2;
'''

E2E_TOML = '''
[[e2e]]
message = "BREMSE_33"
profile = "P01"
data_id_mode = "nibble"
[[e2e]]
message = "BREMSE_10"
profile = "P02"
data_id_list = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16]
[[e2e]]
id = 0x340
profile = "P05"
data_id = 0x0340
[[e2e]]
message = "BREMSE_51"
profile = "P11"
offset = 2
length = 6
'''


def test_e2e_profiles_from_e2e_toml_pass_the_librarys_checks(tmp_path, thirdparty):
    path = thirdparty / "dbc" / "abs.dbc"
    e2e_file = tmp_path / "E2E.toml"
    e2e_file.write_text(E2E_TOML)
    plans, _, frames = collect(RestbusConfig((str(path),), e2e_path=str(e2e_file)), 5.0)
    protected = {p.codec.frame_id: p for p in plans if p.e2e is not None}
    assert {p.e2e.profile for p in protected.values()} == {"P01", "P02", "P05", "P11"}
    counters = {i: AliveCounterCheck(p.e2e.counter_modulo) for i, p in protected.items()}
    lib = {"P01": autosar_e2e.p01.e2e_p01_check, "P02": autosar_e2e.p02.e2e_p02_check,
           "P05": autosar_e2e.p05.e2e_p05_check, "P11": autosar_e2e.p11.e2e_p11_check}
    seen = 0
    for msg in frames:
        plan = protected.get(msg.arbitration_id)
        if plan is None:
            continue
        seen += 1
        assert lib[plan.e2e.profile](bytearray(msg.data), **plan.e2e._kw), plan.name
        assert counters[msg.arbitration_id].check(plan.e2e.counter(msg.data)), plan.name
    assert seen > 1000


def test_a_rerun_is_byte_identical_and_the_log_holds_every_frame(tmp_path, thirdparty):
    path = str(thirdparty / "dbc" / "abs.dbc")
    values = tmp_path / "v.toml"
    values.write_text('[[value]]\nsignal = "BREMSE_33.whlspeed_FL"\nkind = "random_walk"\n'
                      'start = 50\nstep = 0.5\n')
    logs = []
    for k in range(2):
        log = tmp_path / f"r{k}.log"
        res = run_restbus(RestbusRun(RestbusConfig((path,), values_path=str(values), seed=4),
                                     duration_s=1.0, channel=f"rb-rerun-{k}",
                                     log_path=str(log)))
        assert res.summary["logged"] == res.summary["frames_sent"] > 0
        logs.append(log.read_bytes().replace(f"rb-rerun-{k}".encode(), b"CH"))
    assert logs[0] == logs[1]


def test_every_message_of_every_thirdparty_dbc_is_sent_or_skipped_with_its_reason(thirdparty):
    """Each message is accounted for: planned, or in `skipped` with a reason (a message with no
    sender and no cycle time used to vanish from both)."""
    from vecu.codec import DbcCodec

    reasons: set[str] = set()
    for path in dbcs(thirdparty):
        db = DbcCodec([path], strict=False)
        for default in (None, 25.0):
            try:
                plans, skipped, _ = build_plans(RestbusConfig((str(path),),
                                                              default_cycle_ms=default))
            except BadFileError:
                continue
            planned = {p.name for p in plans}
            assert not planned & set(skipped), path.name
            assert planned | set(skipped) == {fc.name for fc in db.by_id.values()}, path.name
            reasons |= set(skipped.values())
    assert "no cycle time" in reasons and "no sender and no cycle time" in reasons, reasons


FD10_DBC = """VERSION ""
BS_:
BU_: Test
BO_ 291 Fd10: 10 Test
 SG_ First : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ Last : 72|8@1+ (1,0) [0|255] "" Vector__XXX
BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","StandardCAN_FD","ExtendedCAN_FD";
BA_DEF_DEF_ "VFrameFormat" "StandardCAN";
BA_ "VFrameFormat" BO_ 291 14;
BA_DEF_ SG_ "GenSigStartValue" INT 0 255;
BA_ "GenSigStartValue" SG_ 291 Last 5;
"""
