"""Monte-Carlo campaigns: many runs with drawn parameters, executed on Dask (docs/campaigns.md).

spec (the TOML file) -> draws (per-run parameters from the run's own seed) -> studies (what one
run computes: an estimator-level manifold study or a full simulated drive) -> engine (Dask, the
incremental runs.csv, resume) -> summary (statistics with confidence intervals, report.html).
"""
