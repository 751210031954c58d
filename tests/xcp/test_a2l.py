"""`vecu a2l`: the A2L parses with pya2l, describes every numeric ecu.* leaf and the ECU's
measurements at the slave's addresses, and follows the tree's XCP IDs."""

from __future__ import annotations

import subprocess
import sys

import pya2l  # noqa: F401 - puts its generated modules on the path (before .parser)
import pytest
from pya2l.parser import A2lParser

from vecu import params as ptree
from vecu.config import ParamTree
from vecu.xcp.memory import code_of


def _a2l(tmp_path, *sets: str) -> str:
    out = tmp_path / "vecu.a2l"
    args = [sys.executable, "-m", "vecu", "a2l", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert "characteristics" in done.stdout
    return out.read_text()


def _parse(text: str):
    with A2lParser() as parser:
        return parser.tree_from_a2l(text.encode())


def _if_data_blob(module, name: str):
    for blob in module.IF_DATA[0].Blob:
        if blob.Generic.Name.Value == name:
            return blob.Generic
    raise AssertionError(f"no {name} in IF_DATA XCP")


def test_every_numeric_ecu_leaf_is_a_characteristic_with_unit_bounds_and_address(tmp_path):
    text = _a2l(tmp_path)
    module = _parse(text).PROJECT.MODULE[0]
    chars = {c.Name.Value: c for c in module.CHARACTERISTIC}
    numeric = [leaf for leaf in ptree.leaves(ParamTree().ecu, "ecu.") if code_of(leaf.value)]
    assert numeric and set(chars) == {leaf.path for leaf in numeric}
    methods = {m.Name.Value: m for m in module.COMPU_METHOD}
    addresses = set()
    for leaf in numeric:
        c = chars[leaf.path]
        assert methods[c.Conversion.Value].Unit.Value == leaf.unit
        assert c.Type == ("VAL_BLK" if isinstance(leaf.value, tuple) else "VALUE")
        addresses.add(c.Address.Value)
    assert len(addresses) == len(numeric)  # one address each
    table = chars["ecu.manifold.kf.params.cd_table"]  # 3 rows of 7
    dim = table.MATRIX_DIM
    assert (dim.XDim.Value, dim.YDim.Value, dim.ZDim.Value) == (7, 3, 1)
    deb = chars["ecu.throttle.tps_monitor.plaus_debounce"]
    assert (deb.LowerLimit.Value, deb.UpperLimit.Value) == (1, 1_000_000_000)
    assert not deb.HasField("READ_ONLY")  # the running ECU takes it
    assert chars["ecu.throttle.noise_scale"].HasField("READ_ONLY")  # built at start
    meas = {m.Name.Value: m for m in module.MEASUREMENT}
    for name in ("throttle.estimate_deg", "throttle.sigma_deg", "throttle.tps_deg",
                 "speed.speed_mps", "manifold.p_im_kpa", "monitor.tps.status",
                 "monitor.tps.value", "monitor.wheel.value", "monitor.swa.value",
                 "monitor.tps.dtc", "rx.crc_errors"):
        assert meas[name].ECU_ADDRESS.Address.Value > 0
    assert meas["throttle.estimate_deg"].DataType.Value == "FLOAT32_IEEE"  # fits a CAN DTO


def test_if_data_follows_the_tree_ids_and_lists_the_events(tmp_path):
    module = _parse(_a2l(tmp_path, "ecu.xcp.master_id=0x600", "ecu.xcp.slave_id=0x601")
                    ).PROJECT.MODULE[0]
    can = _if_data_blob(module, "XCP_ON_CAN")
    values = [e.Long.Value for e in can.Element if e.HasField("Long")]
    assert 0x600 in values and 0x601 in values
    daq = _if_data_blob(module, "DAQ")
    events = [e.Generic for e in daq.Element if e.HasField("Generic")
              and e.Generic.Name.Value == "EVENT"]
    assert [e.Element[0].String.Value for e in events] == ["1ms", "2ms", "10ms", "100ms",
                                                           "engine"]


@pytest.mark.parametrize("sets, message", [
    (["ecu.xcp.master_id=0x7E0"], "clashes with a UDS ID"),
    (["ecu.xcp.slave_id=0x7F0"], "must differ"),
    (["ecu.xcp.enabled=false"], "no A2L"),
])
def test_bad_ids_are_one_line_errors(tmp_path, sets, message):
    args = [sys.executable, "-m", "vecu", "a2l", "--out", str(tmp_path / "x.a2l")]
    for s in sets:
        args += ["--set", s]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 2
    assert done.stderr.startswith("vecu: error:") and message in done.stderr
    assert not (tmp_path / "x.a2l").exists()
