"""The campaign's batch engine (runs of events per compiled call) against the scalar engine
(event by event, as the ECU steps), on the same Table 3 draws: every metric agrees to 1e-9
relative under every kernel backend, the scalar engine on the python backend being the
reference."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

from vecu.campaign.draws import draw, load_campaign
from vecu.campaign.studies import MANIFOLD_METRICS, manifold_study

TABLE3 = Path(__file__).resolve().parents[2] / "vecu/data/campaigns/manifold-table3.toml"


@pytest.fixture(scope="module")
def spec():
    return replace(load_campaign(TABLE3), runs=3)


@pytest.mark.parametrize("run_id", [2])
def test_batch_engine_agrees_with_the_scalar_engine(spec, backend, per_backend, run_id):
    d = draw(spec, run_id)
    ref = per_backend.reference(("scalar", run_id),
                                lambda: manifold_study(d, 3.0, 2, engine="scalar"))
    got = manifold_study(d, 3.0, 2, engine="batch")
    assert set(got) == set(ref) == set(MANIFOLD_METRICS)
    for k in MANIFOLD_METRICS:
        assert math.isclose(got[k], ref[k], rel_tol=1e-9, abs_tol=0.0), (k, got[k], ref[k])
    assert ref["events"] > 120 and ref["sdkf_iae"] > 0.0
    assert ref["direct_iae"] != ref["direct_ol_iae"] != ref["ekf_iae"] != ref["sdkf_iae"]


def test_unknown_engine_is_refused(spec):
    with pytest.raises(ValueError, match="engine"):
        manifold_study(draw(spec, 0), 1.0, 1, engine="fast")
