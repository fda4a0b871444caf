"""The road anomaly detection study and its calibration (``roadcollab anomalies``, ``roadcollab calibrate``)."""
