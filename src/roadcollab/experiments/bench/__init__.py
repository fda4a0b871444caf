"""Timings: the per-segment cost of one vehicle and fleet-scale runs (``roadcollab bench``)."""
