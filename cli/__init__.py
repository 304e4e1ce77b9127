"""Command-line entry points, installed as the `ngsim_cli` package (see pyproject.toml)."""
