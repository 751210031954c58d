"""Shared estimator math: sigma-point sets, covariance guards, the generic unscented filter."""
