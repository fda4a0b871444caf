import os

from hypothesis import settings

# Keep hypothesis' example database out of the work tree and examples deterministic in CI.
settings.register_profile("roadcollab", database=None, deadline=None, derandomize=True)
settings.load_profile("roadcollab")
os.environ.setdefault("MPLBACKEND", "Agg")
