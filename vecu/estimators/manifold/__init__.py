"""Intake manifold pressure/temperature and cylinder air charge (Dutka 2006): EKF, SDKF, CAC prediction."""
