"""The version is written once (ngsim_graphs/version.py): pyproject, both packages, the installed
metadata and CITATION.cff agree, and no module reads it (or anything) from a package's __init__."""

from __future__ import annotations

import ast
import importlib.metadata
import re
import tomllib
from pathlib import Path

import pytest

import aigem
import ngsim_graphs
from ngsim_graphs.version import __version__

ROOT = Path(__file__).resolve().parents[1]


def test_both_packages_re_export_the_one_version() -> None:
    assert re.fullmatch(r"\d+\.\d+\.\d+", __version__)
    assert ngsim_graphs.__version__ == aigem.__version__ == __version__


def test_pyproject_reads_the_version_from_its_module() -> None:
    document = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in document["project"] and document["project"]["dynamic"] == ["version"]
    attr = document["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "ngsim_graphs.version.__version__"
    # One literal and no import: setuptools reads it without importing the package.
    module = ast.parse((ROOT / "ngsim_graphs" / "version.py").read_text())
    statements = [node for node in module.body if not isinstance(node, ast.Expr)]  # docstring
    assert ast.dump(statements[0]) == ast.dump(ast.parse(f"__version__ = {__version__!r}").body[0])
    assert len(statements) == 1
    pyprojecttoml = pytest.importorskip("setuptools.config.pyprojecttoml")  # not in every venv
    assert pyprojecttoml.read_configuration(ROOT / "pyproject.toml")["project"]["version"] == (
        __version__
    )


def test_the_installed_metadata_and_the_citation_agree() -> None:
    try:
        installed = importlib.metadata.version("ngsim-graphs")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("ngsim-graphs is not installed (run from the source tree)")
    assert installed == __version__  # an editable install made before a bump: install again
    citation = re.search(r"^version: (\S+)$", (ROOT / "CITATION.cff").read_text(), re.MULTILINE)
    assert citation is not None and citation.group(1) == __version__


@pytest.mark.parametrize("package", ["ngsim_graphs", "aigem"])
def test_no_module_imports_a_name_from_its_packages_init(package: str) -> None:
    """`from ngsim_graphs import layout` imports a module; `from ngsim_graphs import __version__`
    would be an import of the package's __init__ from below it, the one arrow that runs back up."""
    wrong = []
    for path in sorted((ROOT / package).rglob("*.py")):
        if path.name == "__init__.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module in ("ngsim_graphs", "aigem"):
                folder = ROOT / node.module
                for alias in node.names:
                    name = alias.name
                    if not ((folder / f"{name}.py").is_file() or (folder / name).is_dir()):
                        wrong.append(f"{path.relative_to(ROOT)}: {name}")
    assert wrong == []
