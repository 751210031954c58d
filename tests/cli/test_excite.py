"""`vecu excite throttle --input FILE` (issue 18 item 1): the plant's throttle input u(t) from a
user's file; the recorded wattmeter voltage follows it; a bad file is one line, before any work."""

from __future__ import annotations

import can
import numpy as np
import pytest

from vecu.cli import main
from vecu.codec import DbcCodec


def _wattmeter_voltage(log) -> np.ndarray:
    """ETB_Voltage of every ETB_Wattmeter frame in the trace, in order."""
    msg = DbcCodec()["ETB_Wattmeter"]
    with can.LogReader(str(log)) as reader:
        return np.array([msg.decode(bytes(f.data))["ETB_Voltage"] for f in reader
                         if f.arbitration_id == msg.frame_id])


def test_the_recorded_wattmeter_voltage_follows_the_file(tmp_path, capsys):
    # steps, ramps and a sine, rows every 0.7 ms (not on the 1 ms grid): interpolated
    t = np.arange(0.0, 1.2, 0.0007)
    u = np.where(t < 0.3, 2.0, 8.0) + np.where(t > 0.6, 1.5 * np.sin(2 * np.pi * 3 * t), 0.0)
    u[(t > 0.9)] = 11.0 * (t[t > 0.9] - 0.9) / 0.3
    csv = tmp_path / "u.csv"
    csv.write_text("t_s,u_V\n" + "".join(f"{a:.6f},{b:.6f}\n" for a, b in zip(t, u, strict=True)))
    log = tmp_path / "ex.log"
    assert main(["excite", "throttle", "--input", str(csv), "--log", str(log), "--seed", "1"]) == 0
    assert f"throttle input {csv}" in capsys.readouterr().out
    got = _wattmeter_voltage(log)
    rows = np.loadtxt(csv, delimiter=",", skiprows=1)
    want = np.interp(np.arange(got.size) / 1000.0, rows[:, 0], rows[:, 1])
    assert got.size == round(rows[-1, 0] * 1000)  # default duration: the file's last time
    np.testing.assert_allclose(got, want, atol=0.0006)  # ETB_Voltage resolution 1 mV


def test_a_longer_run_holds_the_last_value(tmp_path):
    csv = tmp_path / "u.csv"
    csv.write_text("t_s,u_V\n0,1\n0.05,6\n")
    log = tmp_path / "ex.log"
    assert main(["excite", "throttle", "--input", str(csv), "--duration", "0.2", "--log",
                 str(log), "--quiet"]) == 0
    got = _wattmeter_voltage(log)
    assert got.size == 200 and got[10] == pytest.approx(2.0) and set(got[50:]) == {6.0}


@pytest.mark.parametrize(("text", "problem"), [
    ("t_s,volts\n0,1\n", "line 1: no u_V column in the header (t_s,volts)"),
    ("t_s,u_V\n0,1\n0.001,x\n", "line 3: u_V 'x' is not a number"),
    ("t_s,u_V\n0,1\n0.002,1\n0.001,1\n", "line 4: t_s 0.001 is not after the previous row's"),
    ("", "empty"),
])
def test_a_bad_input_file_is_one_line_naming_it(tmp_path, capsys, text, problem):
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    log = tmp_path / "never.log"
    assert main(["excite", "throttle", "--input", str(bad), "--log", str(log)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"vecu: error: {bad}: ") and problem in err and "\n" not in err, err
    assert not log.exists()
