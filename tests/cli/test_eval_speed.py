from __future__ import annotations

import json

from vecu.cli import main as cli_main


def test_eval_speed_json_meets_targets_on_the_paper_manoeuvre(capsys):
    assert cli_main(["eval", "speed", "--runs", "3", "--seed", "7", "--json"]) == 0
    (r,) = json.loads(capsys.readouterr().out)
    assert r["manoeuvre"] == "paper" and r["runs"] == 3
    assert r["speed_gain_high_db"] >= 15.0 and r["speed_gain_low_db"] >= 15.0
    assert r["accel_gain_db"] >= 6.0 and r["resets"] == 0


def test_eval_speed_rejects_unknown_manoeuvre(capsys):
    assert cli_main(["eval", "speed", "--manoeuvre", "drift"]) == 2
    err = capsys.readouterr().err
    assert "drift" in err and len(err.strip().splitlines()) == 1
