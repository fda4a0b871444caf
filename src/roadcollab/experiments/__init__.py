"""Studies: reproduction, sweep, security, anomalies, calibration, benchmark, the runner."""
