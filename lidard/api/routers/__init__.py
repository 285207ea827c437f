"""One router per resource: health, devices/scanner, scans, calibration, sim."""
