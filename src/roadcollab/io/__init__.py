"""Recorded drives and profile files."""
