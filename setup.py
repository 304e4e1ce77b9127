"""The package list, discovered rather than written down: every package under ngsim_graphs/ and
aigem/ (a new folder with an `__init__.py` is installed without a word here), and the CLI, whose
sources in cli/ install as `ngsim_cli` (pyproject's package-dir). Everything else is in
pyproject.toml; setuptools reads both."""

from setuptools import find_packages, setup

TOP_LEVEL = ("ngsim_graphs", "aigem")


def packages(where: str = ".") -> list[str]:
    """Every package of the source tree under `where` that a wheel installs."""
    found = find_packages(where, include=[name for top in TOP_LEVEL for name in (top, f"{top}.*")])
    return [*found, "ngsim_cli"]


if __name__ == "__main__":
    setup(packages=packages())
