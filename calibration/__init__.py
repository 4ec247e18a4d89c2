"""msflash: calibration."""
