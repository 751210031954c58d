"""Declarative fault-injection scenarios: TOML files -> runs on the simulated clock -> verdicts.

loader (format, validation), criteria (pass/fail per run), runner (serial or parallel), report
(JUnit XML, HTML with PNG plots). User documentation: docs/scenarios.md.
"""
