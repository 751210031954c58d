"""The papers' equations as pure functions and frozen parameter sets (no state, noise or bus).

Shared by the plant simulators (vecu.plant) and the estimators (vecu.estimators); see
docs/architecture.md.
"""
