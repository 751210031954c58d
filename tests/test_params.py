"""The parameter tree: every leaf documented, overrides parsed and checked, plant and ECU apart.

What a mismatch study needs: `plant.*` (the simulated car) and `ecu.*` (the calibration) are
separate objects, equal by default, and each reaches only its own side of the run.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from vecu import params
from vecu.config import ParamTree, RunConfig
from vecu.errors import UserError
from vecu.params import ParamError
from vecu.runner import run


def test_every_leaf_has_a_unit_and_a_source_and_plant_equals_ecu_by_default():
    tree = ParamTree()
    leaves = list(params.leaves(tree))
    assert len(leaves) > 150
    assert all(leaf.unit and leaf.source for leaf in leaves), [
        leaf.path for leaf in leaves if not (leaf.unit and leaf.source)]
    assert len({leaf.path for leaf in leaves}) == len(leaves)
    # the halves are separate objects that hold the same values where they describe the same car
    assert tree.ecu.manifold.kf.params == tree.plant.manifold.engine
    assert tree.ecu.manifold.kf.params is not None
    assert tree.ecu.throttle.calibration == tree.plant.sensors.tps
    assert tree.ecu.steering.model.params == tree.plant.lateral
    assert tree.ecu.throttle.model == tree.plant.throttle.model  # Table I on both sides
    paper = {leaf.path.split(".", 1)[1] for leaf in leaves if "Table I" in leaf.source}
    assert {"throttle.model.mode1.a12", "throttle.model.mode3.c3"} <= paper


def test_set_parses_to_the_leaf_type_and_leaves_the_rest_alone():
    tree = ParamTree().set([("plant.manifold.engine.v_im_dm3", "5.25"),
                            ("ecu.throttle.tps_monitor.plaus_debounce", "250"),
                            ("ecu.throttle.tps_monitor.enabled", "false"),
                            ("plant.throttle.model.mode_bounds_deg", "7.5, 16")])
    assert tree.plant.manifold.engine.v_im_dm3 == 5.25
    assert tree.ecu.manifold.kf.params.v_im_dm3 == 5.0  # the ECU still believes the nominal one
    assert tree.ecu.throttle.tps_monitor.plaus_debounce == 250
    assert tree.ecu.throttle.tps_monitor.enabled is False
    assert tree.plant.throttle.model.mode_bounds_deg == (7.5, 16.0)
    changed = {leaf.path for leaf in params.differences(tree, ParamTree())}
    assert changed == {"plant.manifold.engine.v_im_dm3", "ecu.throttle.tps_monitor.plaus_debounce",
                       "ecu.throttle.tps_monitor.enabled", "plant.throttle.model.mode_bounds_deg"}


@pytest.mark.parametrize(("path", "value", "message"), [
    ("plant.manifold.engine.v_im_dm", "5", "nearest: plant.manifold.engine.v_im_dm3"),
    ("ecu.throttle.noise_scal", "1", "nearest: ecu.throttle.noise_scale"),
    ("plant.throttle.noise_scale", "abc", "expected a number, got 'abc'"),
    ("plant.throttle.noise_scale", "nan", "expected a finite number"),
    ("plant.throttle.noise_scale", "-1", "must be >= 0"),
    ("ecu.throttle.tps_monitor.timeout_cycles", "2.5", "expected an integer"),
    ("ecu.throttle.estimator", "kalman", "unknown estimator 'kalman'"),
    ("ecu.manifold.filter", "ukf", "expected one of sdkf, ekf"),
    ("plant.manifold.engine", "1", "is a group, not a parameter"),
    ("plant.throttle.model.mode_bounds_deg", "8", "expected 2 values"),
])
def test_bad_paths_and_values_are_one_line_user_errors(path, value, message):
    with pytest.raises(ParamError) as info:
        ParamTree().set([(path, value)])
    assert isinstance(info.value, UserError)
    assert message in str(info.value) and "\n" not in str(info.value)
    assert path.split("[")[0] in str(info.value)


def _score(summary: dict) -> tuple:
    m = summary["manifold"]
    return (json.dumps(m["p_im_error_kpa"]), json.dumps(m["cac_pred6_abs_error_pct"]))


def test_plant_and_ecu_are_apart_in_a_run():
    """A 10 % larger simulated manifold volume changes the plant's frames; the same change in the
    ECU's calibration alone changes only the ECU's estimates; both together differ from each."""
    base = RunConfig(duration_s=1.5, seed=3, kill_tps_at_s=None, steering=False, speed=False)
    runs = {name: run(base.with_params(sets)).summary for name, sets in (
        ("nominal", {}),
        ("plant", {"plant.manifold.engine.v_im_dm3": 5.5}),
        ("ecu", {"ecu.manifold.kf.params.v_im_dm3": 5.5}),
    )}
    p = {k: _score(s) for k, s in runs.items()}
    assert len(set(p.values())) == 3, p
    assert runs["plant"]["config"]["params"] == {"plant.manifold.engine.v_im_dm3": 5.5}
    assert runs["nominal"]["config"]["params"] == {}


def test_plant_throttle_model_is_the_plants_own():
    """Table I of the simulated throttle body can differ from the ECU's (which keeps Table I)."""
    base = RunConfig(duration_s=0.5, seed=2, kill_tps_at_s=None, steering=False, speed=False,
                     manifold=False, keep_series=True)
    a = run(base).throttle_series
    b = run(base.with_params({"plant.throttle.model.mode3.b": 0.05})).throttle_series
    assert a is not None and b is not None
    assert (a.theta_true != b.theta_true).any()


def test_ecu_throttle_model_is_the_estimators_calibration():
    """`ecu.throttle.model` (what `vecu identify throttle` writes) changes the ECU's estimate and
    nothing of the simulated car (issue 18)."""
    base = RunConfig(duration_s=0.5, seed=2, kill_tps_at_s=None, steering=False, speed=False,
                     manifold=False, keep_series=True)
    a = run(base).throttle_series
    b = run(base.with_params({"ecu.throttle.model.mode3.b": 0.05})).throttle_series
    assert a is not None and b is not None
    assert (a.theta_true == b.theta_true).all()
    assert (a.theta_est != b.theta_est).any()


def _vecu(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vecu", *args], check=False, capture_output=True,
                          text=True,
                          timeout=120, env={"VECU_KERNELS": "python", "PATH": "/usr/bin:/bin"})


def test_cli_params_lists_json_and_reports_bad_paths():
    res = _vecu("params", "--json")
    assert res.returncode == 0, res.stderr
    rows = json.loads(res.stdout)
    assert {"path", "value", "unit", "source"} <= set(rows[0])
    assert any(r["path"] == "ecu.manifold.kf.params.omega0" and r["unit"] == "rad/s" for r in rows)
    res = _vecu("params", "--changed", "--set", "plant.sensors.tps.v_at_0=0.4")
    assert res.returncode == 0 and res.stdout.split()[:2] == ["plant.sensors.tps.v_at_0", "0.4"]
    res = _vecu("run", "--duration", "0.1", "--set", "plant.manifold.engine.zeta=abc")
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        "vecu: error: parameter 'plant.manifold.engine.zeta': expected a number, got 'abc'"]
    res = _vecu("ecu", "--set", "plant.throttle.noise_scale=2", "--duration", "0.1")
    assert res.returncode == 2 and "takes ecu.* parameters only" in res.stderr


def test_scenario_set_table_reaches_the_tree_and_bad_paths_name_the_file(tmp_path):
    from vecu.scenario.loader import ScenarioError, load_scenario

    good = tmp_path / "mismatch.toml"
    good.write_text('duration_s = 1.0\n[plant]\nmanifold = true\n'
                    '[set]\n"plant.manifold.engine.v_im_dm3" = 5.5\n'
                    '[set.ecu.throttle.tps_monitor]\nplaus_debounce = 120\n')
    cfg = load_scenario(good).config
    assert cfg.params.plant.manifold.engine.v_im_dm3 == 5.5
    assert cfg.params.ecu.manifold.kf.params.v_im_dm3 == 5.0
    assert cfg.params.ecu.throttle.tps_monitor.plaus_debounce == 120
    bad = tmp_path / "bad.toml"
    bad.write_text('duration_s = 1.0\n[set]\n"plant.manifold.engine.v_im" = 5.5\n')
    with pytest.raises(ScenarioError) as info:
        load_scenario(bad)
    assert str(info.value).startswith(f"{bad}: key 'set': unknown parameter")
    assert "nearest: plant.manifold.engine.v_im_dm3" in str(info.value)


@pytest.mark.parametrize("path,value,message", [
    ("ecu.throttle.tps_monitor.dtc_heal_ms", 1e308, "must be >= 0 and <= 1e+10"),
    ("ecu.throttle.tps_monitor.heal_ms", "-1", "must be >= 0"),
    ("plant.manifold.noise_scale", 1e300, "must be >= 0 and <= 1000"),
    ("plant.throttle.noise_scale", "1e300", "must be >= 0 and <= 1000"),
    ("plant.manifold.engine.tau_temp_s", "1e8", "must be >= 0 and <= 1e+07 s"),
    ("ecu.steering.lag_s", "10", "must be >= 0.01 and <= 4 s"),
    ("plant.manifold.engine.n_cyl", "0", "must be >= 1 and <= 16"),
    ("ecu.manifold.kf.params.max_substeps", "1000000", "must be >= 1 and <= 1000"),
    ("plant.manifold.engine.v_im_dm3", "1e300", "<= 1e+09"),
    ("ecu.manifold.kf.n_range", "300,1e300", "<= 1e+09"),
    ("ecu.throttle.tps_monitor.timeout_cycles", str(2**62), "<= 1e+09"),
])
def test_values_a_run_cannot_honour_are_refused_naming_the_leaf(path, value, message):
    """Issue 14 item 3: dtc_heal_ms = 1e308 or noise_scale = 1e300 passed and crashed the run."""
    with pytest.raises(ParamError) as info:
        ParamTree().set([(path, value)])
    text = str(info.value)
    assert message in text and "\n" not in text and path.split("[")[0] in text, text


def test_every_default_lies_within_its_leaf_bounds():
    from vecu.params import bounds_of, leaves

    for leaf in leaves(ParamTree()):
        lo, hi = bounds_of(leaf.path)
        values = leaf.value if isinstance(leaf.value, tuple) else (leaf.value,)
        flat = [v for x in values for v in (x if isinstance(x, tuple) else (x,))]
        for v in flat:
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                assert lo <= v <= hi, (leaf.path, v, (lo, hi))
    assert bounds_of("ecu.throttle.tps_monitor.dtc_heal_ms") == (0.0, 1e10)
    assert ParamTree().set([("ecu.throttle.tps_monitor.dtc_heal_ms", 1e9)])  # 11.6 days: fine
