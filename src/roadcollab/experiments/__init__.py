"""Studies, one subpackage each (reproduction, sweep, security, anomalies, drives, bench), above the
modules they share: the configuration, the seed plan, the fleet pipeline and the runner."""
