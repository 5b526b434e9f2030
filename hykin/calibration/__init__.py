"""hykin.calibration."""
