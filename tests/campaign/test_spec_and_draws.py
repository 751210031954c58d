"""Campaign files and per-run draws: one-line errors naming file and key; draws that depend on
(seed, run id) alone; Dutka's eps applied to the plant only."""

from __future__ import annotations

import numpy as np
import pytest

from vecu.campaign.draws import draw, load_campaign, tree_for
from vecu.config import ParamTree
from vecu.errors import BadFileError

GOOD = """kind = "manifold"
runs = 10
seed = 5
[run]
duration_s = 2.0
[[vary]]
path = "plant.manifold.engine.h1_w_per_k"
dist = "truncnorm"
sd = 2.5
lo = -5.0
hi = 5.0
apply = "error_pct"
[[vary]]
path = "plant.manifold.sensor_gains[1]"
dist = "uniform"
lo = -2.0
hi = 2.0
apply = "gain_pct"
"""


def _write(tmp_path, text, name="c.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_eps_moves_the_plant_and_leaves_the_ecu_calibration(tmp_path):
    spec = load_campaign(_write(tmp_path, GOOD))
    d = draw(spec, 3)
    eps = d.drawn["plant.manifold.engine.h1_w_per_k"]
    assert -5.0 <= eps <= 5.0
    tree = tree_for(d)
    nominal = ParamTree().plant.manifold.engine.h1_w_per_k
    assert tree.plant.manifold.engine.h1_w_per_k == nominal / (1 + eps / 100)
    assert tree.ecu.manifold.kf.params.h1_w_per_k == nominal
    g = d.drawn["plant.manifold.sensor_gains[1]"]
    assert tree.plant.manifold.sensor_gains == (1.0, 1.0 + g / 100, 1.0)


def test_run_draws_depend_on_seed_and_run_id_only(tmp_path):
    spec = load_campaign(_write(tmp_path, GOOD))
    more = load_campaign(_write(tmp_path, GOOD.replace("runs = 10", "runs = 999"), "m.toml"))
    assert draw(spec, 7) == draw(more, 7)
    assert draw(spec, 7) != draw(spec, 6)
    # run i takes SeedSequence(seed).spawn(n)[i]: same entropy and spawn key
    child = np.random.SeedSequence(5).spawn(10)[7]
    assert child.spawn_key == (7,) and child.entropy == 5
    other = load_campaign(_write(tmp_path, GOOD.replace("seed = 5", "seed = 6"), "o.toml"))
    assert draw(other, 7) != draw(spec, 7)


def test_truncated_gaussian_stays_inside_its_limits(tmp_path):
    spec = load_campaign(_write(tmp_path, GOOD))
    eps = np.array([draw(spec, i).drawn["plant.manifold.engine.h1_w_per_k"] for i in range(400)])
    assert eps.min() >= -5.0 and eps.max() <= 5.0
    assert abs(eps.mean()) < 0.5 and 1.8 < eps.std() < 2.6  # sd 2.5 truncated at 2 sd: 2.0


@pytest.mark.parametrize(("old", "new", "key"), [
    ('kind = "manifold"', 'kind = "rocket"', "key 'kind'"),
    ("runs = 10", "runs = 0", "key 'runs'"),
    ('dist = "truncnorm"', 'dist = "gamma"', "key 'vary[0].dist'"),
    ("sd = 2.5", "sd = -1.0", "key 'vary[0].sd'"),
    ("hi = 5.0", "hi = -9.0", "key 'vary[0].hi'"),
    ('path = "plant.manifold.engine.h1_w_per_k"', 'path = "plant.manifold.engine.h1"',
     "key 'vary[0].path': unknown parameter 'plant.manifold.engine.h1'"),
    ('path = "plant.manifold.sensor_gains[1]"', 'path = "plant.manifold.sensor_gains[7]"',
     "key 'vary[1].path'"),
    ("[run]", "[run]\nspeed = true", "key 'run.speed'"),
    ('apply = "gain_pct"', 'apply = "cube"', "key 'vary[1].apply'"),
])
def test_bad_campaign_files_are_one_line_naming_file_and_key(tmp_path, old, new, key):
    assert old in GOOD
    path = _write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(BadFileError) as info:
        load_campaign(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: ") and key in msg and "\n" not in msg


def test_unreadable_campaign_file(tmp_path):
    bad = tmp_path / "bin.toml"
    bad.write_bytes(b"\xff\xfe\x00kind")
    with pytest.raises(BadFileError, match="not UTF-8 text"):
        load_campaign(bad)
    with pytest.raises(BadFileError, match="no such file"):
        load_campaign(tmp_path / "missing.toml")


def test_shipped_campaigns_load(repo_root):
    for name in ("manifold-table3", "tps-kill-latency", "false-alarms"):
        spec = load_campaign(repo_root / "vecu" / "data" / "campaigns" / f"{name}.toml")
        assert spec.name == name and spec.runs >= 100
    t3 = load_campaign(repo_root / "vecu" / "data" / "campaigns" / "manifold-table3.toml")
    assert t3.runs == 2000 and len(t3.vary) == 9
    limits = {v.path: (v.lo, v.hi) for v in t3.vary}
    assert limits["plant.manifold.engine.eta_n_val"] == (-4.0, 4.0)
    assert limits["plant.manifold.engine.cd_table"] == (-3.0, 3.0)
    assert limits["plant.manifold.sensor_gains[0]"] == (-3.0, 3.0)
