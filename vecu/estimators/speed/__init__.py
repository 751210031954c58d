"""Vehicle speed and acceleration at 500 Hz (Hernandez 2005): Kalman filter and LQG/LTR design."""
