"""Shared set-up of the routing tests: a two-bus gateway config (vecu's database on
"powertrain", the body database of tests/gateway/data on "vehicle") written next to its DBC."""

from __future__ import annotations

import shutil
from pathlib import Path

DATA = Path(__file__).parent / "data"

TWO_BUSES = '''
[buses.powertrain]
interface = "virtual"
channel = "pt"
dbc = ["vecu"]

[buses.vehicle]
interface = "virtual"
channel = "veh"
dbc = ["body.dbc"]
'''

ROUTES = TWO_BUSES + '''
[[routes]]
from = "powertrain"
to = "vehicle"
messages = ["ECU_SpeedEstimate"]
id = 0x420
min_interval_ms = 20

[[routes]]
from = "powertrain"
to = "vehicle"
target = "VEH_Dynamics"
send = "cyclic"
timeout_ms = 100
signals = { VEH_Speed = "ECU_SpeedEstimate.SPD_VehSpeed", VEH_Throttle = "ECU_ThrottleEstimate.THR_Angle", VEH_Source = "ECU_ThrottleEstimate.THR_Source" }
e2e = { profile = "P11", data_id = 0x421 }

[[routes]]
from = "powertrain"
to = "vehicle"
target = "VEH_Mux"
send = "on_change"
signals = { VEH_Yaw = "CHS_Lateral.LAT_YawRate" }

[[deny]]
from = "vehicle"
ids = [0x7E0, 0x7DF]
'''


def write_config(tmp_path: Path, text: str = ROUTES) -> Path:
    shutil.copy(DATA / "body.dbc", tmp_path / "body.dbc")
    path = tmp_path / "gw.toml"
    path.write_text(text)
    return path
