"""The routing half of the gateway config: the example file read back, and every bad input as one
line naming the file, the key and the problem, before any bus opens."""

from __future__ import annotations

import pytest

from vecu.errors import UserError
from vecu.gateway.config import GatewayConfigError, load_gateway_config
from vecu.gateway.routes_config import load_routing_config

from .routing_setup import TWO_BUSES, write_config

SIGNAL_ROUTE = '''
[[routes]]
from = "powertrain"
to = "vehicle"
target = "VEH_Dynamics"
'''


def test_the_example_reads_back(tmp_path):
    path = write_config(tmp_path)
    cfg = load_routing_config(path)
    assert [b.name for b in cfg.buses] == ["powertrain", "vehicle"]
    assert dict(cfg.buses[1].args) == {"interface": "virtual", "channel": "veh"}
    (frame,) = cfg.frame_routes
    assert frame.ids == frozenset({(0x220, False)}) and frame.new_id == 0x420
    assert frame.min_interval_ns == 20_000_000
    dyn, mux = cfg.signal_routes
    assert dyn.cycle_ns == 20_000_000 and dyn.timeout_ns == 100_000_000
    assert dyn.e2e is not None and dyn.e2e.profile == "P11" and dyn.e2e.data_id == 0x421
    speed = next(m for m in dyn.signals if m.target == "VEH_Speed")
    assert (speed.message, speed.signal) == ("ECU_SpeedEstimate", "SPD_VehSpeed")
    assert speed.factor == pytest.approx(1 / 3.6)  # km/h -> m/s, the units the DBCs name
    assert mux.mux == (("VEH_Page", 2),)
    assert cfg.deny[0].ids == frozenset({0x7E0, 0x7DF})
    # the DoIP half of the same file still reads (the routing tables are its keys too)
    assert load_gateway_config(path).logical_address == 0x1000


BAD = [
    ("unknown bus", TWO_BUSES + SIGNAL_ROUTE.replace('"vehicle"', '"chassis"'),
     "key 'routes[0].to': unknown bus 'chassis' (buses: powertrain, vehicle)"),
    ("own bus", TWO_BUSES + SIGNAL_ROUTE.replace('to = "vehicle"', 'to = "powertrain"'),
     "key 'routes[0].to': routes to the bus it comes from ('powertrain')"),
    ("unknown target message", TWO_BUSES + SIGNAL_ROUTE.replace("VEH_Dynamics", "VEH_Nope"),
     "key 'routes[0].target': unknown message 'VEH_Nope' on bus 'vehicle'"),
    ("unknown source message", TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Speed = "X.Y" }',
     "key 'routes[0].signals.VEH_Speed': unknown message 'X' on bus 'powertrain'"),
    ("unknown source signal",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Speed = "ECU_SpeedEstimate.Nope" }',
     "key 'routes[0].signals.VEH_Speed': message ECU_SpeedEstimate has no signal 'Nope'"),
    ("unknown target signal",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { Nope = "ECU_SpeedEstimate.SPD_VehSpeed" }',
     "key 'routes[0].signals.Nope': message VEH_Dynamics has no signal 'Nope'"),
    ("unit that does not fit",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Throttle = "ENG_Intake.ENG_IAT" }',
     ("key 'routes[0].signals.VEH_Throttle': unit 'degC' of ENG_Intake.ENG_IAT cannot become "
     "'deg'")),
    ("range outside",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_HotAir = "ENG_Intake.ENG_IAT" }',
     ("key 'routes[0].signals.VEH_HotAir': ENG_Intake.ENG_IAT's range [-60, 180] does not fit "
     "VEH_HotAir's [200, 455]")),
    ("choices that do not fit",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Source = "ECU_SpeedEstimate.SPD_Mode" }',
     ("key 'routes[0].signals.VEH_Source': choices ['abs', 'coast', 'normal', 'standstill'] of "
     "ECU_SpeedEstimate.SPD_Mode are not choices of VEH_Source")),
    ("choices only on one side",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Source = "ECU_SpeedEstimate.SPD_VehAccel" }',
     ("key 'routes[0].signals.VEH_Source': ECU_SpeedEstimate.SPD_VehAccel and VEH_Source: choices "
     "map by name, only one has choices")),
    ("E2E header over a signal",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Speed = "ECU_SpeedEstimate.SPD_VehSpeed" }\n'
     'e2e = { profile = "P11", data_id = 1, offset = 2 }',
     "key 'routes[0].e2e': P11's header (bytes 2..3) overlaps target signal VEH_Speed"),
    ("E2E header too big",
     TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Speed = "ECU_SpeedEstimate.SPD_VehSpeed" }\n'
     'e2e = { profile = "P07", data_id = 1 }',
     ("key 'routes[0].e2e': does not fit VEH_Dynamics: P07 needs 20 bytes (header of 20 at offset "
     "0), the message protects 8")),
    ("two writers", TWO_BUSES + (SIGNAL_ROUTE + 'signals = { VEH_Speed = '
                                 '"ECU_SpeedEstimate.SPD_VehSpeed" }\n') * 2,
     "key 'routes[1].target': 0x0500 on bus 'vehicle' is already sent by routes[0]"),
    ("loop", TWO_BUSES + '''
[[routes]]
from = "powertrain"
to = "vehicle"
ids = [0x300]
[[routes]]
from = "vehicle"
to = "powertrain"
id = 0x300
mask = 0x7F0
''', ("key 'routes[1]': a loop with routes[0]: powertrain 0x0300 -> vehicle 0x0300 -> "
     "powertrain 0x0300")),
    ("ID out of range", TWO_BUSES + '[[routes]]\nfrom = "powertrain"\nto = "vehicle"\n'
     'messages = ["ECU_SpeedEstimate"]\nid = 0x20000000\n',
     "key 'routes[0].id': 0x20000000 is outside 0..0x1FFFFFFF"),
    ("unknown E2E profile", TWO_BUSES + SIGNAL_ROUTE + 'signals = { VEH_Speed = '
     '"ECU_SpeedEstimate.SPD_VehSpeed" }\ne2e = { profile = "P99" }',
     "key 'routes[0].e2e': unknown E2E profile 'P99' (known: P01, P02, P04, P05, P07, P11)"),
    ("two selector values", TWO_BUSES + SIGNAL_ROUTE.replace("VEH_Dynamics", "VEH_Mux")
     + 'send = "on_change"\nsignals = { VEH_Yaw = "CHS_Lateral.LAT_YawRate", '
       'VEH_Accel = "ESC_Motion.ESC_LongAccel" }',
     "key 'routes[0].signals.VEH_Accel': needs VEH_Page in [1], another target needs 2"),
    ("bad send", TWO_BUSES + SIGNAL_ROUTE + 'send = "sometimes"',
     "key 'routes[0].send': expected one of cyclic, on_change, both, got 'sometimes'"),
    ("missing dbc", TWO_BUSES.replace('["body.dbc"]', '["nowhere.dbc"]'), "key 'buses.vehicle.dbc': "),
]


@pytest.mark.parametrize(("text", "message"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input_is_one_line_naming_file_and_key(tmp_path, text, message):
    path = write_config(tmp_path, text)
    with pytest.raises(GatewayConfigError) as info:
        load_routing_config(path)
    assert isinstance(info.value, UserError)
    line = str(info.value)
    assert "\n" not in line and line.startswith(f"{path}: {message}")
