"""report.html and summary.json answer the campaign's question (issue 29 item 3): results split
by every categorical draw, intervals that fit each metric (a share's Wilson interval, nothing
negative for a non-negative metric), bars for true/false metrics and no histogram for constant
ones, the runs an alarm flags with a ready rerun command, 4 significant digits. Rows shaped as
tps-kill-latency's (fault kind drawn): fast detection for the hard faults, slow and partial for
the soft ones, one false alarm; the report is also opened in headless Chromium where present."""

from __future__ import annotations

import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from vecu.campaign.draws import load_campaign
from vecu.campaign.engine import columns
from vecu.campaign.summary import format_summary, summarise, write_report

ROOT = Path(__file__).resolve().parents[2]
HARD = ("dead", "short_supply", "stuck", "frames_stop")
RUNS = 70
FALSE_ALARM_RUN = 33


@pytest.fixture(scope="module")
def campaign():
    spec = load_campaign(ROOT / "vecu" / "data" / "campaigns" / "tps-kill-latency.toml")
    rng = np.random.default_rng(5)
    kinds = [str(c) for c in spec.vary[0].choices]
    rows = []
    for i in range(RUNS):
        kind = kinds[i % len(kinds)]
        hard = kind in HARD
        detected = hard or rng.random() < 0.65
        row = {c: "" for c in columns(spec)}
        row.update({"run_id": str(i), "sim_seed": str(1000 + i), "status": "ok",
                    "draw:fault.kind": kind, "draw:fault.at_s": repr(float(rng.uniform(2, 6)))})
        for c in row:
            if c.startswith("draw:plant"):
                row[c] = repr(float(rng.normal(0, 1)))
        row.update({
            "detected": "true" if detected else "false",
            "detection_latency_ms": (repr(float(rng.uniform(1.3, 7.6) if hard
                                                else rng.uniform(260, 1600)))
                                     if detected else ""),
            "false_alarm": "true" if i == FALSE_ALARM_RUN else "false",
            "after_kill_rms_deg": repr(float(rng.gamma(2.0, 0.4))),
            "after_kill_max_deg": repr(float(rng.gamma(2.0, 1.0))),
            "missing_broadcasts": "0", "nan_outputs": "0"})
        rows.append(row)
    return spec, rows


def test_the_summary_answers_by_fault_kind_with_intervals_that_fit(campaign):
    spec, rows = campaign
    s = summarise(spec, rows)
    lat = s["metrics"]["detection_latency_ms"]
    assert lat["ci_method"] == "bootstrap" and 0 <= lat["min"] <= lat["mean_ci95"][0]
    fa = s["metrics"]["false_alarm"]
    assert fa["kind"] == "proportion" and fa["successes"] == 1 and fa["n"] == RUNS
    lo, hi = fa["mean_ci95"]
    assert 0 < lo < 1 / RUNS < hi < 0.1  # Wilson: not [-0.017, 0.05] as Student t gave
    assert s["metrics"]["nan_outputs"]["kind"] == "constant"
    by = s["by"]["fault.kind"]
    assert list(by) == [str(c) for c in spec.vary[0].choices]  # the file's order
    for kind, g in by.items():
        d = g["metrics"]["detection_latency_ms"]
        assert (d["mean"] < 10) if kind in HARD else (d["mean"] > 200), kind
        assert g["metrics"]["detected"]["kind"] == "proportion"
        assert 0 <= g["metrics"]["detected"]["mean_ci95"][0]
        assert g["metrics"]["detected"]["mean_ci95"][1] <= 1
    assert s["flagged_runs"] == [{"run_id": FALSE_ALARM_RUN, "sim_seed": str(1000 + FALSE_ALARM_RUN),
                                  "alarms": ["false_alarm"]}]
    assert "p5" not in fa and "p50" in lat  # no percentiles of true/false values
    text = format_summary(s)
    assert "by fault.kind (mean [95 % interval]):" in text and "run 33 (false_alarm)" in text
    assert "mean [95 % confidence interval of the mean" in text
    (fa_line,) = [ln for ln in text.splitlines() if ln.strip().startswith("false_alarm ")]
    assert "p50" not in fa_line


class _Images(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.src: list[str] = []

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.src.append(dict(attrs)["src"])


def test_the_report_shows_each_kind_flags_the_alarm_and_prints_4_digits(campaign, tmp_path):
    spec, rows = campaign
    write_report(spec, rows, summarise(spec, rows), tmp_path)
    page = (tmp_path / "report.html").read_text()
    assert "<h2>By fault.kind</h2>" in page
    assert f"vecu campaign rerun {tmp_path} {FALSE_ALARM_RUN}" in page  # DIR filled in
    assert "Runs an alarm flags (1)" in page
    for number in re.findall(r"\d+\.\d+", page):  # 4 significant digits at most
        assert len(number.replace(".", "").lstrip("0")) <= 4, number
    images = _Images()
    images.feed(page)
    assert "hist_false_alarm.png" in images.src and "hist_detected.png" in images.src  # bars
    assert "hist_nan_outputs.png" not in images.src  # constant: no empty histogram
    assert "hist_missing_broadcasts.png" not in images.src
    for src in images.src:  # every figure the page shows is there and is a PNG
        assert (tmp_path / src).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.skipif(not (shutil.which("chromium") or shutil.which("chromium-browser")),
                    reason="headless Chromium not installed (apt-get install chromium)")
def test_the_report_renders_in_headless_chromium(campaign, tmp_path):
    import matplotlib.image

    spec, rows = campaign
    write_report(spec, rows, summarise(spec, rows), tmp_path)
    shot = tmp_path / "shot.png"
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    res = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                          f"--screenshot={shot}", "--window-size=1200,4000",
                          (tmp_path / "report.html").as_uri()],
                         capture_output=True, text=True, timeout=120, check=False)
    assert shot.exists(), res.stderr
    img = matplotlib.image.imread(shot)
    assert img.shape[0] >= 4000 and img.shape[1] >= 1200
    # the figures drew: plenty of the page is neither white nor text-black (bars, histograms)
    rgb = img[..., :3]
    coloured = (rgb.max(axis=-1) - rgb.min(axis=-1)) > 0.2
    assert coloured.mean() > 0.01
