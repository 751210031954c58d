"""Faults on gateway routes from a scenario's [[faults]] (target = the route's key) with an
inline [gateway] table: drop, stop, delay and corrupt, each verified by what appears on the
vehicle bus in the run's log, each start and end as an FI_Event frame on the first bus."""

from __future__ import annotations

from dataclasses import replace

import can
import cantools
import pytest

from vecu.codec import builtin_dbc_path
from vecu.scenario.batch import run_scenario
from vecu.scenario.loader import ScenarioError, load_scenario

from .routing_setup import DATA, ROUTES

VECU_DB = cantools.database.load_file(str(builtin_dbc_path()))
FAULTS = """
[[faults]]
target = "routes[0]"
kind = "drop"
value = 2
start_s = 0.105
[[faults]]
target = "routes[0]"
kind = "stop"
start_s = 0.3
end_s = 0.4
[[faults]]
target = "routes[0]"
kind = "delay"
value = 5
start_s = 0.5
end_s = 0.6
[[faults]]
target = "routes[0]"
kind = "corrupt"
value = 1
start_s = 0.7
end_s = 0.8
"""


def _scenario(tmp_path, faults: str = FAULTS):
    (tmp_path / "body.dbc").write_text((DATA / "body.dbc").read_text())
    gateway = ROUTES.replace("[buses.", "[gateway.buses.").replace("[[routes]]", "[[gateway.routes]]"
                                                                   ).replace("[[deny]]", "[[gateway.deny]]")
    path = tmp_path / "s.toml"
    path.write_text(f'name = "route-faults"\nduration_s = 1.0\n[plant]\nspeed = true\n{gateway}\n{faults}')
    return load_scenario(path)


@pytest.fixture(scope="module")
def faulted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("faults")
    scenario = _scenario(tmp)
    log = tmp / "run.log"
    outcome = run_scenario(replace(scenario, config=replace(scenario.config, log_path=str(log))))
    return outcome, log


def test_route_faults_show_on_the_target_bus(faulted):
    outcome, log = faulted
    assert outcome.error is None
    routed: dict[int, bytes] = {}   # ms -> 0x420 payload on the vehicle bus
    source: dict[int, bytes] = {}   # ms -> the latest ECU_SpeedEstimate then
    latest = b""
    events = []
    with can.LogReader(str(log)) as reader:
        for m in reader:
            ms = round(m.timestamp * 1000)
            if m.channel == "powertrain" and m.arbitration_id == 0x220:
                latest = bytes(m.data)
            elif m.channel == "powertrain" and m.arbitration_id == 0x6F1:
                ev = VECU_DB.decode_message(0x6F1, bytes(m.data), decode_choices=True)
                events.append((ms, str(ev["FI_EvKind"]), str(ev["FI_EvActive"]) == "start",
                               ev["FI_EvMessageId"]))
            elif m.channel == "vehicle" and m.arbitration_id == 0x420:
                routed[ms] = bytes(m.data)
                source[ms] = latest
    healthy = set(range(0, 1000, 20))
    dropped = {120, 140} | set(range(300, 400, 20))           # drop 2 from 105 ms, stop 300..400
    delayed = set(range(500, 600, 20))                        # 5 ms late
    assert set(routed) == (healthy - dropped - delayed) | {t + 5 for t in delayed}
    for ms, data in routed.items():
        if 700 <= ms < 800:  # corrupt: byte 1 inverted, the rest as the source sent it
            assert data[1] == source[ms][1] ^ 0xFF and data[:1] + data[2:] == \
                source[ms][:1] + source[ms][2:]
        elif ms % 20 == 0:
            assert data == source[ms]
    assert events == [(105, "drop", True, 0x420), (140, "drop", False, 0x420),
                      (300, "stop", True, 0x420), (400, "stop", False, 0x420),
                      (500, "rb_delay", True, 0x420), (600, "rb_delay", False, 0x420),
                      (700, "corrupt", True, 0x420), (800, "corrupt", False, 0x420)]


def test_a_bad_route_fault_is_one_line(tmp_path):
    with pytest.raises(ScenarioError, match=r"faults\[0\]\.kind.*one of drop, stop, delay, corrupt"):
        _scenario(tmp_path, '[[faults]]\ntarget = "routes[1]"\nkind = "babble"\nstart_s = 0.1\n')
    with pytest.raises(ScenarioError, match=r"faults\[0\]\.kind.*corrupt.*\[0, 63\]"):
        _scenario(tmp_path, '[[faults]]\ntarget = "routes[1]"\nkind = "corrupt"\nvalue = 99\n'
                            'start_s = 0.1\n')


def test_a_campaign_run_routes_with_its_gateway(tmp_path):
    """A drive campaign's [run] gateway = "gw.toml" (beside the campaign file): each run routes,
    and a route's figures are metrics like any summary value."""
    from vecu.campaign.draws import load_campaign
    from vecu.campaign.studies import run_one

    from .routing_setup import write_config

    write_config(tmp_path)
    metric = "gateway.routes.routes[0] powertrain->vehicle.out"
    (tmp_path / "c.toml").write_text(f'kind = "drive"\nruns = 2\nmetrics = ["{metric}"]\n'
                                     '[run]\nduration_s = 0.5\ngateway = "gw.toml"\n')
    spec = load_campaign(str(tmp_path / "c.toml"))
    row = run_one(spec, 0)
    assert row["status"] == "ok", row
    assert row[metric] == 25  # ECU_SpeedEstimate every 2 ms, at most one per 20 ms: 0..480 ms


def test_a_campaign_gateway_error_is_one_line(tmp_path):
    from vecu.campaign.spec import read_campaign
    from vecu.errors import UserError

    (tmp_path / "gw.toml").write_text('[buses.a]\ninterface = "virtual"\ndbc = ["nope.dbc"]\n')
    (tmp_path / "c.toml").write_text('kind = "drive"\n[run]\ngateway = "gw.toml"\n')
    with pytest.raises(UserError, match=r"gw\.toml: key 'buses\.a\.dbc'"):
        read_campaign(str(tmp_path / "c.toml"))
