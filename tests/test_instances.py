"""Several ECUs on one bus (vecu.instances, docs/live.md 'Several ECUs on one bus'): the ID rule
for every instance, the parameter tree's follow rule, the user errors, and two ECUs of instance
0 and 1 on one virtual bus told apart by a udsoncan tester and by their frames."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import can
import isotp
import pytest

from vecu.assembly import TICK_NS, build_functions, build_plant, schedule_ecu, schedule_plant
from vecu.bus import open_bus
from vecu.clock import SimClock
from vecu.codec import DbcCodec, builtin_dbc_path
from vecu.config import ParamTree, RunConfig
from vecu.ecu.node import EcuNode
from vecu.errors import ConfigError
from vecu.faults import FaultInjector
from vecu.functions import function_codec
from vecu.instances import (
    ECU_NODE,
    FRAME_STRIDE,
    MAX_INSTANCE,
    ecu_frame_id,
    uds_ids,
    xcp_ids,
)
from vecu.params import ParamError
from vecu.scheduler import Scheduler
from vecu.uds.server import attach_uds

from .uds.sim import drive_tester

INSTANCES = range(MAX_INSTANCE + 1)
DOCS = Path(__file__).resolve().parents[1] / "docs" / "live.md"


def _ecu_ids(n: int) -> dict[int, str]:
    """Every CAN ID ECU instance n sends or answers on (its frames by the codec of instance n)."""
    codec = function_codec(n)
    ids = {codec.by_id[key].frame_id: codec.by_id[key].name for key in codec.sent_by(ECU_NODE)}
    ids.update({v: f"uds.{k}" for k, v in uds_ids(n).items() if k != "functional_id"})
    ids.update({v: f"xcp.{k}" for k, v in xcp_ids(n).items()})
    assert len(ids) == len(codec.sent_by(ECU_NODE)) + 4, f"instance {n}: two of its IDs collide"
    return ids


def test_instance_zero_is_the_dbc_and_the_old_defaults():
    dbc = DbcCodec([builtin_dbc_path()])
    codec = function_codec(0)
    for key in dbc.sent_by(ECU_NODE):
        assert codec.by_id[key].name == dbc.by_id[key].name
    tree = ParamTree()
    assert (tree.ecu.instance, tree.ecu.uds.request_id, tree.ecu.uds.response_id,
            tree.ecu.uds.functional_id, tree.ecu.xcp.master_id, tree.ecu.xcp.slave_id) == (
        0, 0x7E0, 0x7E8, 0x7DF, 0x7F0, 0x7F1)


@pytest.mark.parametrize("n", INSTANCES)
def test_the_rule_for_instance(n):
    assert uds_ids(n) == {"request_id": 0x7E0 + n, "response_id": 0x7E8 + n, "functional_id": 0x7DF}
    assert xcp_ids(n) == {"master_id": 0x7F0 + 2 * n, "slave_id": 0x7F1 + 2 * n}
    dbc = DbcCodec([builtin_dbc_path()])
    moved = function_codec(n)
    for key in dbc.sent_by(ECU_NODE):
        name = dbc.by_id[key].name
        assert moved[name].frame_id == key[0] + n * FRAME_STRIDE == ecu_frame_id(key[0], n)
        if moved[name].e2e is not None:  # the E2E data ID is the moved CAN ID
            assert moved[name].e2e.protection.data_id == moved[name].frame_id
    # the tree follows the instance
    tree = ParamTree().set([("ecu.instance", n)])
    assert {k: getattr(tree.ecu.uds, k) for k in uds_ids(n)} == uds_ids(n)
    assert {k: getattr(tree.ecu.xcp, k) for k in xcp_ids(n)} == xcp_ids(n)


def test_no_instance_collides_with_another_or_with_any_other_vecu_id():
    """Over instances 0..7: every ID any instance uses is unique, and none is an ID of a
    message vecu's DBCs give another node (plant, tester, truth) or the shared functional ID."""
    others = {key[0]: fc.name for key, fc in function_codec(0).by_id.items()
              if ECU_NODE not in fc.senders}
    others[0x7DF] = "uds.functional_id"
    owner: dict[int, str] = {}
    for n in INSTANCES:
        for can_id, name in _ecu_ids(n).items():
            assert can_id <= 0x7FF
            assert can_id not in others, f"instance {n} {name} on {others[can_id]}'s 0x{can_id:X}"
            assert can_id not in owner, f"instance {n} {name} on {owner[can_id]}'s 0x{can_id:X}"
            owner[can_id] = f"instance {n} {name}"


def test_an_id_set_by_hand_stays_and_the_others_follow():
    tree = ParamTree().set([("ecu.instance", 2), ("ecu.uds.request_id", 0x700)])
    assert (tree.ecu.uds.request_id, tree.ecu.uds.response_id, tree.ecu.xcp.master_id) == (
        0x700, 0x7EA, 0x7F4)
    later = tree.set([("ecu.instance", 1)])  # set earlier, still the user's
    assert (later.ecu.uds.request_id, later.ecu.uds.response_id) == (0x700, 0x7E9)
    back = later.set([("ecu.instance", 0)])
    assert (back.ecu.uds.response_id, back.ecu.xcp.slave_id) == (0x7E8, 0x7F1)


@pytest.mark.parametrize(("sets", "words"), [
    ([("ecu.uds.request_id", 0x300)], "ecu.uds.request_id and frame ECU_Status share the CAN ID 0x300"),
    ([("ecu.instance", 1), ("ecu.xcp.master_id", 0x260)],
     "ecu.xcp.master_id and frame ECU_ThrottleEstimate share the CAN ID 0x260"),
    ([("ecu.instance", 8)], "ecu.instance"),
])
def test_a_collision_or_a_bad_instance_is_a_user_error(sets, words):
    with pytest.raises(ParamError, match=re.escape(words)):
        ParamTree().set(sets)


def test_a_frame_moved_out_of_range_is_a_config_error():
    with pytest.raises(ConfigError, match="outside the 11-bit range"):
        ecu_frame_id(0x7C0, 1)
    assert ecu_frame_id(0x1FFF_0000, 7, extended=True) == 0x1FFF_0000 + 7 * FRAME_STRIDE


def test_ecu_cli_refuses_colliding_ids_in_one_line(capsys):
    from vecu.cli import main as cli_main

    assert cli_main(["ecu", "--instance", "1", "--set", "ecu.uds.response_id=0x361",
                     "--duration", "0.2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "share the CAN ID 0x361" in err[0], err


def test_docs_table_is_the_rule():
    """docs/live.md's table of instances: each row's IDs are the rule's."""
    rows = [line for line in DOCS.read_text().splitlines() if re.match(r"\| [0-7] \|", line)]
    assert len(rows) == MAX_INSTANCE + 1
    for n, row in enumerate(rows):
        cells = [c.strip() for c in row.strip("|").split("|")]
        codec = function_codec(n)
        assert cells[0] == str(n)
        assert cells[1] == f"0x{0x7E0 + n:X} / 0x{0x7E8 + n:X}"
        assert cells[2] == f"0x{0x7F0 + 2 * n:X} / 0x{0x7F1 + 2 * n:X}"
        assert cells[3] == (f"0x{codec['ECU_ThrottleEstimate'].frame_id:X}-"
                            f"0x{codec['ECU_SteeringSigma'].frame_id:X}")
        assert cells[4] == (f"0x{codec['ECU_Status'].frame_id:X} / "
                            f"0x{codec['ECU_Diag'].frame_id:X}")


# ------------------------------------------------------------- two ECUs on one virtual bus

class TwoEcus:
    """One plant and two ECUs (instance 0: throttle + manifold, serial VECU-00000; instance 1:
    throttle + speed + steering, serial VECU-00001) on one virtual channel, simulated clock."""

    def __init__(self, channel: str) -> None:
        self.buses = [open_bus("virtual", channel) for _ in range(4)]
        self.channel = channel
        plant_cfg = RunConfig(duration_s=600.0, kill_tps_at_s=None)
        self.plant = build_plant(plant_cfg, function_codec(0), self.buses[0],
                                 FaultInjector(__import__("numpy").random.default_rng(0)))
        self.sched = Scheduler(SimClock())
        schedule_plant(self.sched, self.plant)
        self.ecus, self.configs = [], []
        for n, parts in ((0, {"speed": False, "steering": False}), (1, {"manifold": False})):
            cfg = RunConfig(duration_s=600.0, kill_tps_at_s=None, **parts).with_params(
                [("ecu.instance", n), ("ecu.uds.serial", f"VECU-0000{n}")])
            codec = function_codec(n)
            ecu = EcuNode(self.buses[1 + n], codec, build_functions(cfg, codec).enabled())
            assert attach_uds(ecu, cfg.params.ecu.uds, 0) is not None
            schedule_ecu(self.sched, ecu)
            self.ecus.append(ecu)
            self.configs.append(cfg)
        self.listener = self.buses[3]  # sees every frame the others send
        self.t_ns = 0

    def step(self, ticks: int = 1) -> None:
        self.t_ns += ticks * TICK_NS
        self.sched.run_until(self.t_ns)

    def ask(self, instance: int, work) -> Any:
        """work(client) by a udsoncan tester at instance's physical IDs, the clock stepping."""
        bus = open_bus("virtual", self.channel)
        self.buses.append(bus)
        ids = uds_ids(instance)
        stack = isotp.CanStack(bus, address=isotp.Address(
            isotp.AddressingMode.Normal_11bits, txid=ids["request_id"], rxid=ids["response_id"]),
            params={"tx_padding": 0xCC, "blocking_send": False})
        return drive_tester(stack, work, self.step, max_ticks=60_000)

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()


@pytest.fixture
def two_ecus(request):
    rig = TwoEcus(f"instances-{request.node.name}")
    yield rig
    rig.close()


def test_two_ecus_on_one_bus_answer_each_at_its_own_ids(two_ecus):
    rig = two_ecus
    rig.step(200)
    while rig.listener.recv(0) is not None:  # start listening now
        pass
    for n in (0, 1):
        serial = rig.ask(n, lambda c: c.read_data_by_identifier(0xF18C).service_data.values[0xF18C])
        assert serial == f"VECU-0000{n}"
        vin = rig.ask(n, lambda c: c.read_data_by_identifier(0xF190).service_data.values[0xF190])
        assert vin == rig.configs[n].params.ecu.uds.vin
    assert rig.ecus[0].diagnostics.stats.requests == 2  # type: ignore[union-attr]
    assert rig.ecus[1].diagnostics.stats.requests == 2  # type: ignore[union-attr]


def test_two_ecus_broadcast_their_frames_at_distinct_ids(two_ecus):
    rig = two_ecus
    rig.step(50)
    while rig.listener.recv(0) is not None:
        pass
    rig.step(300)
    seen: dict[int, list[can.Message]] = {}
    while (msg := rig.listener.recv(0)) is not None:
        seen.setdefault(msg.arbitration_id, []).append(msg)
    frames = {n: function_codec(n) for n in (0, 1)}
    expect = {0: ("ECU_ThrottleEstimate", "ECU_ManifoldEstimate", "ECU_Status", "ECU_Diag"),
              1: ("ECU_ThrottleEstimate", "ECU_SpeedEstimate", "ECU_SteeringEstimate",
                  "ECU_Status", "ECU_Diag")}
    absent = {0: ("ECU_SpeedEstimate", "ECU_SteeringEstimate"), 1: ("ECU_ManifoldEstimate",)}
    for n, codec in frames.items():
        for name in expect[n]:
            fc = codec[name]
            msgs = seen.get(fc.frame_id)
            assert msgs, f"instance {n}: no {name} at 0x{fc.frame_id:X}"
            for msg in msgs[:20]:  # each decodes, its E2E CRC (data ID = moved ID) right
                assert fc.crc_ok(msg.data)
                assert fc.decode_problem(msg.data) is None
                assert fc.decode(msg.data)
        for name in absent[n]:
            assert codec[name].frame_id not in seen, f"instance {n} sends {name}"
    # the two throttle estimates are two streams: both near the same angle, on their own IDs
    thr = [frames[n]["ECU_ThrottleEstimate"] for n in (0, 1)]
    assert thr[0].frame_id != thr[1].frame_id
    angles = [thr[n].decode(seen[thr[n].frame_id][-1].data)["THR_AngleEst"] for n in (0, 1)]
    assert abs(angles[0] - angles[1]) < 5.0
    # instance 1's frame is not instance 0's: its CRC fails under instance 0's data ID
    payload = seen[thr[1].frame_id][-1].data
    assert not thr[0].crc_ok(payload)


@pytest.mark.parametrize("name", ["uds_tps_dtc", "xcp_tps_debounce"])
def test_a_shipped_scenario_passes_on_another_instance(tmp_path, name):
    """The scenario's UDS tester / XCP master and its checks follow `ecu.instance`."""
    from vecu.scenario.batch import run_scenario
    from vecu.scenario.loader import load_scenario
    from vecu.shipped import shipped_files

    path = tmp_path / f"{name}.toml"
    path.write_text(shipped_files("scenario")[name].read_text() + '\n[set]\n"ecu.instance" = 3\n')
    scenario = load_scenario(path)
    assert scenario.config.params.ecu.uds.request_id == 0x7E3
    outcome = run_scenario(scenario)
    assert outcome.error is None and outcome.passed, outcome
