"""Per-run draws: run i of a campaign with seed S takes SeedSequence(S).spawn(...)[i]
(SeedSequence(S, spawn_key=(i,))), so its parameters and its simulation seed depend on (S, i)
alone: the same on 1 worker, N workers or a remote cluster, in any completion order."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import truncnorm

from vecu import params as ptree
from vecu.campaign.spec import CampaignSpec, Vary, read_campaign
from vecu.config import ParamTree
from vecu.errors import BadFileError

_INDEX = re.compile(r"^(.*)\[(\d+)\]$")


@dataclass(frozen=True)
class RunDraw:
    run_id: int
    sim_seed: int  # seeds the run's drive, plant noise and faults (vecu.rng streams)
    drawn: dict[str, Any]  # path -> the drawn number or choice (before `apply`)
    sets: tuple[tuple[str, Any], ...]  # resulting tree overrides (path, leaf value)
    fault: dict[str, Any]  # drive campaigns: kind, at_s, value (empty: no fault)


def run_seed_sequence(seed: int, run_id: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(seed, spawn_key=(run_id,))


def _sample(v: Vary, rng: np.random.Generator) -> Any:
    if v.dist == "fixed":
        return v.value
    if v.dist == "choice":
        return v.choices[int(rng.integers(len(v.choices)))]
    if v.dist == "uniform":
        return float(rng.uniform(v.lo, v.hi))
    a, b = (v.lo - v.mean) / v.sd, (v.hi - v.mean) / v.sd
    return float(truncnorm.rvs(a, b, loc=v.mean, scale=v.sd, random_state=rng))


def _scaled(nominal: Any, factor: float, how: str) -> Any:
    if isinstance(nominal, tuple):
        return tuple(_scaled(x, factor, how) for x in nominal)
    if how == "scale":
        return nominal * factor
    return nominal / (1.0 + factor / 100.0)  # error_pct: actual = modelled / (1 + eps/100)


def leaf_value(tree: ParamTree, path: str, drawn: Any, how: str) -> tuple[str, Any]:
    """(leaf path, new leaf value) for a drawn number; `path[i]` addresses a tuple element."""
    m = _INDEX.match(path)
    leaf, index = (m.group(1), int(m.group(2))) if m else (path, None)
    nominal = ptree.get(tree, leaf)
    current = nominal[index] if index is not None else nominal
    if how == "value":
        new = drawn
    elif how == "gain_pct":
        new = 1.0 + float(drawn) / 100.0
    else:
        new = _scaled(current, float(drawn), how)
    if index is not None:
        items = list(nominal)
        items[index] = new
        new = tuple(items)
    return leaf, new


def draw(spec: CampaignSpec, run_id: int) -> RunDraw:
    """Run run_id's parameters: each [[vary]] entry in file order from the run's own stream."""
    params_ss, sim_ss = run_seed_sequence(spec.seed, run_id).spawn(2)
    rng = np.random.Generator(np.random.PCG64(params_ss))
    base = ParamTree().set(spec.fixed)
    drawn: dict[str, Any] = {}
    sets: list[tuple[str, Any]] = list(spec.fixed)
    fault: dict[str, Any] = {}
    for v in spec.vary:
        x = _sample(v, rng)
        drawn[v.path] = x
        if v.path.startswith("fault."):
            fault[v.path[6:]] = x
        else:
            sets.append(leaf_value(base, v.path, x, v.apply))
    sim_seed = int(sim_ss.generate_state(1, dtype=np.uint32)[0])
    return RunDraw(run_id, sim_seed, drawn, tuple(sets), fault)


def tree_for(d: RunDraw) -> ParamTree:
    return ParamTree().set(d.sets)


def check_spec(spec: CampaignSpec) -> None:
    """Fail now, naming the file and the key, if run 0's draws do not fit the tree."""
    for i, v in enumerate(spec.vary):
        if v.path.startswith("fault."):
            continue
        probe = {"fixed": v.value, "choice": v.choices[0] if v.choices else None,
                 "uniform": (v.lo + v.hi) / 2.0}.get(v.dist, v.mean)
        try:
            leaf_value(ParamTree(), v.path, probe, v.apply)
        except ptree.ParamError as exc:
            raise BadFileError(spec.path, f"key 'vary[{i}].path': {exc}") from None
        except (IndexError, TypeError) as exc:
            raise BadFileError(spec.path, f"key 'vary[{i}].path': {v.path!r}: {exc}") from None
    try:
        tree_for(draw(spec, 0))
    except ptree.ParamError as exc:
        raise BadFileError(spec.path, f"key 'vary'/'set': {exc}") from None
    if any(not math.isfinite(x) for x in _numbers(draw(spec, 0).drawn.values())):
        raise BadFileError(spec.path, "key 'vary': a draw is not finite")


def _numbers(values: Any) -> list[float]:
    return [float(x) for x in values if isinstance(x, (int, float)) and not isinstance(x, bool)]


def load_campaign(path: str) -> CampaignSpec:
    """Read a campaign file and check it against the parameter tree (one line per problem)."""
    spec = read_campaign(path)
    check_spec(spec)  # every path exists, every value fits its leaf (one draw, as run 0 would)
    return spec
