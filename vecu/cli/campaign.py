"""`vecu campaign run FILE|NAME`, `vecu campaign list|show` / `vecu campaign rerun DIR RUN_ID`: Monte-Carlo campaigns on Dask."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from vecu import argtypes
from vecu.cli import check_outputs, configure_logging
from vecu.cli.shipped import register_list_show


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="Monte-Carlo campaigns over parameter spreads, on Dask",
                       description="Many runs with parameters drawn per run (docs/campaigns.md).")
    csub = p.add_subparsers(dest="campaign_command", required=True)
    r = csub.add_parser("run", help="run a campaign (a file or a shipped name)",
                        description="Run every run of a campaign file on a Dask cluster: a local "
                                    "one (--workers) or an existing one (--scheduler). Rows go to "
                                    "DIR/runs.csv as they finish; DIR/summary.json and "
                                    "DIR/report.html at the end.")
    r.add_argument("file", metavar="FILE|NAME",
                   help="campaign .toml file or the name of a shipped one (`vecu campaign list`); "
                        "an existing file wins over a name")
    r.add_argument("--runs", type=argtypes.bounded(1, 10_000_000, integer=True), metavar="N",
                   help="number of runs (default: the file's)")
    r.add_argument("--seed", type=argtypes.seed, help="campaign seed (default: the file's)")
    where = r.add_mutually_exclusive_group()
    where.add_argument("--workers", type=argtypes.bounded(1, 1024, integer=True), metavar="N",
                       help="local Dask worker processes (default: the machine's cores)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="submit to a running Dask scheduler instead")
    r.add_argument("--out", type=argtypes.out_dir, metavar="DIR", help="results directory (default: out/<name>)")
    r.add_argument("--resume", action="store_true", help="complete the runs missing in DIR")
    r.add_argument("--json", action="store_true", help="print the summary as JSON")
    prog = r.add_mutually_exclusive_group()
    prog.add_argument("--progress", action="store_true", default=None,
                      help="always show the progress line (default: on a terminal)")
    prog.add_argument("--no-progress", dest="progress", action="store_false")
    r.set_defaults(func=main_run)
    rr = csub.add_parser("rerun", help="repeat one run of a campaign alone, verbosely",
                         description="Repeat run RUN_ID of the campaign in DIR in this process "
                                     "(same drawn parameters and seed) and print its row.")
    rr.add_argument("dir", metavar="DIR")
    rr.add_argument("run_id", type=argtypes.bounded(0, None, integer=True), metavar="RUN_ID")
    rr.set_defaults(func=main_rerun)
    register_list_show(csub, "campaign")


def _spec(path: str, runs: int | None = None, seed: int | None = None):
    from vecu.campaign.draws import load_campaign

    spec = load_campaign(path)
    if runs is not None:
        spec = replace(spec, runs=int(runs))
    if seed is not None:
        spec = replace(spec, seed=int(seed))
    return spec


def main_run(args: argparse.Namespace) -> int:
    from vecu.campaign.engine import default_progress_stream, run_campaign
    from vecu.campaign.summary import format_summary

    configure_logging(quiet=True)
    from vecu.shipped import resolve

    spec = _spec(str(resolve("campaign", args.file)), args.runs, args.seed)
    out = Path(args.out) if args.out else Path("out") / spec.name
    if not args.out:  # the default place, checked as --out is (before the cluster starts)
        check_outputs(out=argtypes.OutputPath(str(out), "dir"))
    stream = (sys.stderr if args.progress else None) if args.progress is not None \
        else default_progress_stream()
    from vecu.campaign.engine import CampaignInterrupted
    from vecu.live.children import EXIT_TERMINATED, sigterm_unwinds

    try:
        with sigterm_unwinds():
            res = run_campaign(spec, out, workers=args.workers, scheduler=args.scheduler,
                               resume=args.resume, progress=stream)
    except CampaignInterrupted as exc:
        print(f"vecu: {exc}; `{_resume_command(args, out)}` finishes it", file=sys.stderr)
        return 130 if exc.signal_name == "SIGINT" else EXIT_TERMINATED
    if args.json:
        print(json.dumps(res.summary, indent=1))
    else:
        print(format_summary(res.summary))
        print(f"vecu campaign: {res.done}/{res.runs} runs in {out} ({res.new} new, "
              f"{res.failed} failed); report {out / 'report.html'}")
    return 0


def _resume_command(args: argparse.Namespace, out: Path) -> str:
    """The command that completes an interrupted campaign (same file, runs, seed, place)."""
    import shlex

    cmd = ["vecu", "campaign", "run", args.file]
    if args.runs is not None:
        cmd += ["--runs", str(args.runs)]
    if args.seed is not None:
        cmd += ["--seed", str(args.seed)]
    if args.workers is not None:
        cmd += ["--workers", str(args.workers)]
    if args.scheduler:
        cmd += ["--scheduler", args.scheduler]
    return shlex.join([*cmd, "--out", str(out), "--resume"])


def main_rerun(args: argparse.Namespace) -> int:
    from vecu.campaign.draws import draw
    from vecu.campaign.engine import META_JSON, SPEC_COPY
    from vecu.campaign.studies import run_one
    from vecu.errors import BadArgumentError, BadFileError

    d = Path(args.dir)
    if not (d / SPEC_COPY).is_file() or not (d / META_JSON).is_file():
        raise BadFileError(d, "not a campaign results directory (no campaign.toml / meta.json)")
    meta = json.loads((d / META_JSON).read_text())
    spec = replace(_spec(str(d / SPEC_COPY)), seed=int(meta["seed"]), runs=int(meta["runs"]))
    if args.run_id >= spec.runs:
        raise BadArgumentError(f"RUN_ID {args.run_id}: the campaign has runs 0..{spec.runs - 1}")
    configure_logging(quiet=False)
    dr = draw(spec, args.run_id)
    print(f"run {args.run_id}: sim seed {dr.sim_seed}")
    for path, value in dr.sets:
        print(f"  set {path} = {value}")
    if dr.fault:
        print(f"  fault {dr.fault}")
    row = run_one(spec, args.run_id)
    print(json.dumps(row, indent=1))
    return 0 if row["status"] == "ok" else 1
