"""The documentation against the code: docs/build-format.md names every column, array and manifest
key of a real build; every relative link of the README and docs/ points at a file; every package
of the source tree is installed; the packages' public names resolve."""

from __future__ import annotations

import importlib
import inspect
import json
import re
import tomllib
from pathlib import Path

import numpy as np
import polars as pl
import pytest

import aigem
import ngsim_graphs
from ngsim_graphs import layout
from ngsim_graphs.build import open_build
from ngsim_graphs.export import graph_tables

ROOT = Path(__file__).resolve().parents[1]
BUILD_FORMAT = ROOT / "docs" / "build-format.md"


def _named(text: str) -> set[str]:
    """Every `name` in backticks of a Markdown text (also each name of `a`, `b` lists), code
    blocks left out."""
    prose = re.sub(r"^```.*?^```", "", text, flags=re.MULTILINE | re.DOTALL)
    spans = re.findall(r"`([^`\n]+)`", prose)
    return {name for span in spans for name in re.split(r"[,\s]+", span)}


def test_build_format_names_every_column_and_array_of_a_build(tiny_build: Path) -> None:
    named = _named(BUILD_FORMAT.read_text())
    columns = {
        column
        for path in tiny_build.rglob("*.parquet")
        for column in pl.read_parquet_schema(path).names()
    }
    arrays = {path.stem for path in tiny_build.rglob("*.npy")}
    assert columns and arrays
    assert columns - named == set()
    assert arrays - named == set()
    assert set(layout.SAMPLE_ARRAYS) <= arrays


def test_build_format_states_each_array_dtype_as_built(tiny_build: Path) -> None:
    """Each array row of the tables says the dtype the build writes."""
    text = BUILD_FORMAT.read_text()
    for path in tiny_build.rglob("*.npy"):
        rows = re.findall(rf"^\| `{path.stem}` \| (\w+) \| \(", text, re.MULTILINE)  # (shape)
        assert rows == [np.load(path, mmap_mode="r").dtype.name], path.stem


def test_build_format_names_every_manifest_key(tiny_build: Path) -> None:
    named = _named(BUILD_FORMAT.read_text())
    manifest = json.loads(layout.manifest_path(tiny_build).read_text())
    keys = set(manifest)
    for section in ("config", "counts", "scaler", "software", "splits"):
        keys |= set(manifest[section])
    for section in ("inputs", "recordings"):
        keys |= {key for entry in manifest[section] for key in entry}
    keys.add("max_dropped_share")  # of config.limits; the other limits are PhysicalLimits' own
    assert keys - named == set()


def test_build_format_names_every_column_of_the_export_tables(tiny_build: Path) -> None:
    build = open_build(tiny_build)
    tables = graph_tables(build.graphs("train", np.arange(2)), np.arange(2))
    named = _named(BUILD_FORMAT.read_text())
    assert {column for table in tables.values() for column in table.columns} - named == set()


def _links(path: Path) -> list[str]:
    return [
        link.split("#")[0]
        for link in re.findall(r"\]\(([^)]+)\)", path.read_text())
        if not link.startswith(("http://", "https://", "#"))
    ]


@pytest.mark.parametrize("page", ["README.md", "CONTRIBUTING.md", *sorted(
    p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md")
)])  # fmt: skip
def test_relative_links_point_at_files(page: str) -> None:
    path = ROOT / page
    missing = [link for link in _links(path) if not (path.parent / link).exists()]
    assert missing == []


def test_every_package_of_the_source_tree_is_installed() -> None:
    """pyproject lists its packages by hand: a subpackage left out is missing from a wheel."""
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for top in ("ngsim_graphs", "aigem")
        for init in (ROOT / top).rglob("__init__.py")
    }
    assert found - listed == set()


@pytest.mark.parametrize("package", [ngsim_graphs, aigem])
def test_public_names_resolve(package) -> None:  # noqa: ANN001
    for name in package.__all__:
        assert getattr(package, name) is not None, name
    assert package.__all__ == ["__version__", *package._EXPORTS]
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        package.nothing  # noqa: B018
    for name, module in package._EXPORTS.items():
        assert getattr(package, name) is getattr(importlib.import_module(module), name)


# Parameters that name a file or folder, by name: every public function or class that has one
# must take a str as well as a Path (the README writes `load_model("demo/run")`).
PATH_PARAMETERS = {"root", "build_dir", "run_dir", "raw_paths", "out_dir", "path"}


def _path_taking() -> set[str]:
    """The public names (of both packages) whose signature has a parameter in PATH_PARAMETERS."""
    found = set()
    for package in (ngsim_graphs, aigem):
        for name in package._EXPORTS:
            obj = getattr(package, name)
            try:
                parameters = inspect.signature(obj).parameters
            except ValueError:  # a builtin without a signature
                continue
            if PATH_PARAMETERS & set(parameters):
                found.add(name)
    return found


def test_every_public_path_taking_function_takes_a_str(
    tiny_build: Path, tiny_run: Path, tiny_horizons_run: Path, tmp_path: Path
) -> None:
    """Each exported function or class that takes a path, called with str paths: none may fail
    on a str (it did: load_model("demo/run") raised AttributeError: 'str' object has no
    attribute 'exists')."""
    from aigem.config import ModelConfig, TrainConfig
    from ngsim_graphs.config import BuildConfig

    build, run, horizons = str(tiny_build), str(tiny_run), str(tiny_horizons_run)
    raw = str(tiny_build.parent / "raw")
    tiny = BuildConfig(d_sense_m=12.0, d_min_m=6.0)
    one_epoch = TrainConfig(epochs=1, batch_size=64, horizon_s=1.0, max_minutes=None)
    checks = {
        "open_build": lambda: ngsim_graphs.open_build(build).manifest.splits["test"] > 0,
        "verify_build": lambda: ngsim_graphs.verify_build(build).problems == (),
        "run_build": lambda: (
            ngsim_graphs.run_build(raw, str(tmp_path / "b"), tiny).out_dir == tmp_path / "b"
        ),
        "GraphDataset": lambda: len(aigem.GraphDataset(build, "test")) > 0,
        "GraphPygDataset": lambda: len(aigem.GraphPygDataset(build, "test")) > 0,
        "load_model": lambda: aigem.load_model(run)[0].config == ModelConfig(),
        "evaluate": lambda: aigem.evaluate(run, build, device_choice="cpu").samples > 0,
        "evaluate_horizons": lambda: (
            aigem.evaluate_horizons(horizons, device_choice="cpu").horizons_s == (1.0, 2.0)
        ),
        "predict_samples": lambda: (
            aigem.predict_samples(run, build, "test", [0])[1]["AiGem"].shape[1:] == (10, 2)
        ),
        "fit": lambda: (
            aigem.fit(build, str(tmp_path / "r"), ModelConfig(), one_epoch, "cpu").best_epoch == 1
        ),
        "fit_horizons": lambda: (
            len(
                aigem.fit_horizons(
                    build, str(tmp_path / "h"), (1.0,), ModelConfig(), one_epoch, "cpu"
                )
            )
            == 1
        ),
        "NgsimError": lambda: (
            str(ngsim_graphs.NgsimError("a.txt", "bad", line=3)) == "a.txt, line 3: bad"
        ),
        "NgsimInputError": lambda: isinstance(
            ngsim_graphs.NgsimInputError("a.txt", "bad"), ngsim_graphs.NgsimError
        ),
    }
    # OpenBuild is made by open_build, not by its callers; the list is checked against the
    # signatures, so that a new path-taking export gets a check here.
    assert set(checks) == _path_taking() - {"OpenBuild"}
    failed = {name: check() for name, check in checks.items()}
    assert failed == dict.fromkeys(checks, True)
