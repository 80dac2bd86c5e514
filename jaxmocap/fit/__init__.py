"""Fitting: the solver wrappers (the only jaxopt caller), inverse kinematics, shape calibration."""
