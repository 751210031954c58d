"""State estimators by family (estimators.registry ESTIMATORS) on shared sigma-point and covariance math (common)."""
