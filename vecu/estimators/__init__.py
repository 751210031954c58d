"""State estimators by family (throttle, speed, steering, manifold) on shared sigma-point and covariance math (common)."""
