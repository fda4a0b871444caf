"""The parameter sweep over the reproduction (``roadcollab sweep``)."""
