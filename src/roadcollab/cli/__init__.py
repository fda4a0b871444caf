"""The ``roadcollab`` command line."""
