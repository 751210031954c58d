"""`vecu eval steering` and `vecu eval manifold` through the CLI (short runs; the full-length
accuracy targets are asserted in tests/estimators/steering/test_filters.py and tests/estimators/manifold/test_filters.py)."""

from __future__ import annotations

import json

from vecu.cli import main as cli_main


def test_eval_steering_json_orders_the_estimators(capsys):
    assert cli_main(["eval", "steering", "--duration", "30", "--seed", "2", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["samples"] == 3001
    assert r["swa_rms_ukf_deg"] <= 1.3 and r["swa_rms_smoother_deg"] <= 0.4
    assert r["swa_rms_smoother_deg"] < r["swa_rms_ukf_deg"] < r["swa_rms_inverse_deg"]


def test_eval_manifold_table_ranks_filters_above_direct_measurement(capsys):
    assert cli_main(["eval", "manifold", "--duration", "20", "--no-dare", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    ratio = {m["method"]: m["abs_ratio"] for m in r["methods"]}
    assert ratio["direct"] == 1.0
    assert ratio["ekf"] <= 0.5 and ratio["sdkf"] <= 0.5 and ratio["direct_ol"] < 1.0
    assert r["p_im_range_ok"] and all(f["resets"] == 0 for f in r["filters"])


def test_eval_rejects_bad_ranges(capsys):
    assert cli_main(["eval", "steering", "--duration", "0.1"]) == 2
    assert cli_main(["eval", "manifold", "--duration", "500"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("vecu: error:") for line in err)
