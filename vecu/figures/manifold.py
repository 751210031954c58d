"""Dutka 2006 Fig. 4 / Fig. 5 (histograms of the integrated squared / absolute 6-event CAC
prediction error under the Table 2 errors): the Table 3 campaign (shipped manifold-table3)
at a small run count, its runs done here one after the other, its report's histograms kept."""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from pathlib import Path

import numpy as np

from vecu.campaign.draws import load_campaign
from vecu.campaign.studies import METHODS, run_one
from vecu.campaign.summary import summarise, write_report
from vecu.shipped import shipped_files

CAMPAIGN = "manifold-table3"  # shipped (vecu/data/campaigns/)


def make(out: Path, quick: bool = False) -> list[tuple[Path, str]]:
    spec = load_campaign(str(shipped_files("campaign")[CAMPAIGN]))
    runs, duration = (6, 20.0) if quick else (60, 80.0)
    spec = dataclasses.replace(spec, runs=runs, run={**spec.run, "duration_s": duration})
    rows = [{k: str(v) for k, v in run_one(spec, i).items()} for i in range(runs)]
    done = []
    with tempfile.TemporaryDirectory() as tmp:
        write_report(spec, rows, summarise(spec, rows), Path(tmp))
        for fig, key, what in (("fig4", "ise", "squared"), ("fig5", "iae", "absolute")):
            path = out / f"manifold_{fig}_cac_{key}_histogram.png"
            shutil.copyfile(Path(tmp) / f"hist_{key}.png", path)
            means = {m: float(np.mean([float(r[f"{m}_{key}"]) for r in rows
                                       if r.get("status") == "ok"])) for m in METHODS}
            done.append((path, f"integrated {what} error, {runs} runs of {duration:g} s, mean "
                         + ", ".join(f"{m} {v:.4g}" for m, v in means.items())))
    return done
