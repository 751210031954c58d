"""Steering-wheel angle and side-slip (Khalid): UKF/EKF and unscented smoothers."""
