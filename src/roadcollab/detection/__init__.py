"""Road anomaly detection and its scoring."""
