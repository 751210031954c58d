"""Campaign files (TOML): what one run is, how many, which parameters vary and how.

Every problem is one BadFileError line naming the file, the key and the reason, e.g.
``campaigns/x.toml: key 'vary[2].sd': must be > 0, got -1``. Format: docs/campaigns.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vecu.errors import BadFileError
from vecu.functions import OPTIONAL
from vecu.params import flatten_toml
from vecu.tomlfile import read_toml

KINDS = ("manifold", "drive")
DISTS = ("truncnorm", "uniform", "choice", "fixed")
APPLY = ("value", "scale", "error_pct", "gain_pct")
# Special (non-tree) paths a drive campaign may vary: the fault of the run.
FAULT_PATHS = ("fault.kind", "fault.at_s", "fault.value")
MAX_RUNS = 10_000_000


@dataclass(frozen=True)
class Vary:
    """One varied parameter: a distribution and how the drawn number is applied to the leaf.

    apply: "value" sets the leaf; "scale" multiplies the nominal leaf (elementwise for tables);
    "error_pct" is Dutka's eps = 100 (par_modelled - par_actual) / par_actual for a model
    parameter, i.e. actual = nominal / (1 + eps / 100); "gain_pct" sets a sensor gain 1 + eps/100.
    """

    path: str
    dist: str
    apply: str = "value"
    mean: float = 0.0
    sd: float = 1.0
    lo: float = -math.inf
    hi: float = math.inf
    choices: tuple[Any, ...] = ()
    value: Any = None


@dataclass(frozen=True)
class CampaignSpec:
    path: str
    name: str
    description: str
    kind: str
    runs: int
    seed: int
    run: dict[str, Any] = field(default_factory=dict)  # kind-specific settings ([run] table)
    vary: tuple[Vary, ...] = ()
    fixed: tuple[tuple[str, Any], ...] = ()  # [set] table: the same override in every run
    metrics: tuple[str, ...] = ()  # drive: summary paths (empty: the kind's defaults)


ENGINES = ("batch", "scalar")  # manifold studies: runs of events per compiled call, or stepped
RUN_KEYS = {"manifold": {"duration_s": float, "stride": int, "engine": str},
            "drive": {"duration_s": float, **dict.fromkeys(OPTIONAL, bool), "gateway": Path}}


def _fail(path: str, key: str, reason: str) -> BadFileError:
    return BadFileError(path, f"key '{key}': {reason}")


def _number(path: str, key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise _fail(path, key, f"expected a finite number, got {v!r}")
    return float(v)


def _vary(path: str, i: int, item: Any, kind: str) -> Vary:
    pre = f"vary[{i}]"
    if not isinstance(item, dict):
        raise _fail(path, pre, "expected a table")
    known = {"path", "dist", "apply", "mean", "sd", "lo", "hi", "choices", "value"}
    for k in item:
        if k not in known:
            raise _fail(path, f"{pre}.{k}", f"unknown key (known: {', '.join(sorted(known))})")
    for req in ("path", "dist"):
        if req not in item:
            raise _fail(path, f"{pre}.{req}", "required key missing")
    p, dist, apply = item["path"], item["dist"], item.get("apply", "value")
    if not isinstance(p, str) or not p:
        raise _fail(path, f"{pre}.path", "expected a dotted parameter path")
    if p.startswith("fault.") and (kind != "drive" or p not in FAULT_PATHS):
        raise _fail(path, f"{pre}.path", f"fault paths are {', '.join(FAULT_PATHS)} "
                                         f"(drive campaigns only)")
    if dist not in DISTS:
        raise _fail(path, f"{pre}.dist", f"expected one of {', '.join(DISTS)}, got {dist!r}")
    if apply not in APPLY:
        raise _fail(path, f"{pre}.apply", f"expected one of {', '.join(APPLY)}, got {apply!r}")
    kw: dict[str, Any] = {}
    for k in ("mean", "sd", "lo", "hi"):
        if k in item:
            kw[k] = _number(path, f"{pre}.{k}", item[k])
    if dist == "truncnorm":
        if "sd" not in kw or kw["sd"] <= 0:
            raise _fail(path, f"{pre}.sd", f"must be > 0, got {item.get('sd')!r}")
        if "lo" not in kw or "hi" not in kw:
            raise _fail(path, pre, "truncnorm needs lo and hi (the variation limits)")
    if dist == "uniform" and ("lo" not in kw or "hi" not in kw):
        raise _fail(path, pre, "uniform needs lo and hi")
    if dist in ("truncnorm", "uniform") and not kw["lo"] < kw["hi"]:
        raise _fail(path, f"{pre}.hi", f"must be above lo = {kw['lo']:g}, got {kw['hi']:g}")
    if dist == "truncnorm" and not kw["lo"] <= kw.get("mean", 0.0) <= kw["hi"]:
        raise _fail(path, f"{pre}.mean", "must lie within [lo, hi]")
    choices: tuple[Any, ...] = ()
    if dist == "choice":
        c = item.get("choices")
        if not isinstance(c, list) or not c:
            raise _fail(path, f"{pre}.choices", "expected a non-empty array")
        choices = tuple(c)
    if dist == "fixed" and "value" not in item:
        raise _fail(path, f"{pre}.value", "required key missing for dist = 'fixed'")
    if apply in ("error_pct", "gain_pct") and dist in ("truncnorm", "uniform") and (
            kw["lo"] <= -100.0):
        raise _fail(path, f"{pre}.lo", "a percentage error must stay above -100")
    return Vary(p, dist, apply, choices=choices, value=item.get("value"), **kw)


def read_campaign(path: str | Path) -> CampaignSpec:
    """Read a campaign file and check its keys and values (vecu.campaign.draws.load_campaign
    also checks the paths against the parameter tree); every problem is one BadFileError line."""
    path = str(path)
    data = read_toml(path)
    top = {"name", "description", "kind", "runs", "seed", "run", "vary", "set", "metrics"}
    for k in data:
        if k not in top:
            raise _fail(path, k, f"unknown key (known: {', '.join(sorted(top))})")
    kind = data.get("kind")
    if kind not in KINDS:
        raise _fail(path, "kind", f"expected one of {', '.join(KINDS)}, got {kind!r}")
    runs, seed = data.get("runs", 100), data.get("seed", 0)
    if isinstance(runs, bool) or not isinstance(runs, int) or not 1 <= runs <= MAX_RUNS:
        raise _fail(path, "runs", f"expected an integer in 1..{MAX_RUNS}, got {runs!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise _fail(path, "seed", f"expected an integer >= 0, got {seed!r}")
    run = data.get("run", {})
    if not isinstance(run, dict):
        raise _fail(path, "run", "expected a table")
    for k, v in run.items():
        want = RUN_KEYS[kind].get(k)
        if want is None:
            raise _fail(path, f"run.{k}", f"unknown key for kind '{kind}' "
                                          f"(known: {', '.join(RUN_KEYS[kind])})")
        if want is Path:  # a gateway config beside the campaign file: checked now, one line
            if not isinstance(v, str):
                raise _fail(path, f"run.{k}", f"expected a path, got {v!r}")
            from vecu.gateway.routes_config import load_routing_config
            run[k] = str(Path(path).parent / v)
            if not load_routing_config(run[k]).buses:
                raise _fail(path, f"run.{k}", f"{v} names no [buses.NAME] to route")
        if want is str and v not in ENGINES:
            raise _fail(path, f"run.{k}", f"expected one of {', '.join(ENGINES)}, got {v!r}")
        if want is bool and not isinstance(v, bool):
            raise _fail(path, f"run.{k}", f"expected true or false, got {v!r}")
        if want is int and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise _fail(path, f"run.{k}", f"expected an integer >= 1, got {v!r}")
        if want is float and not 0 < _number(path, f"run.{k}", v) <= 86_400:
            raise _fail(path, f"run.{k}", f"expected (0, 86400] s, got {v!r}")
    items = data.get("vary", [])
    if not isinstance(items, list):
        raise _fail(path, "vary", "expected an array of tables ([[vary]])")
    vary = tuple(_vary(path, i, item, kind) for i, item in enumerate(items))
    fixed = data.get("set", {})
    if not isinstance(fixed, dict):
        raise _fail(path, "set", "expected a table")
    metrics = data.get("metrics", [])
    if not isinstance(metrics, list) or not all(isinstance(m, str) for m in metrics):
        raise _fail(path, "metrics", "expected an array of names")
    return CampaignSpec(path, str(data.get("name", Path(path).stem)),
                        str(data.get("description", "")), kind, runs, seed, dict(run), vary,
                        tuple(flatten_toml(fixed)), tuple(metrics))
