"""Recorded and simulated drives: per-vehicle and fleet estimation, distance maps, the road survey."""
