"""Reports, CSV and figures (the only place matplotlib is imported)."""
