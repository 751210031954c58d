"""Throttle angle from the wattmeter (Vargas et al. 2015): paper UKFs and the production estimator."""
