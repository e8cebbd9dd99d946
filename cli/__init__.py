"""The `depthruler` command line: :mod:`cli.main` assembles one module per group of commands."""
