"""The ``roadcollab`` command line: one module per subcommand, dispatched by :mod:`roadcollab.cli.main`."""
