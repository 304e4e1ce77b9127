"""The documentation against the code: docs/build-format.md names every column, array and manifest
key of a real build; every relative link of the README and docs/ points at a file; every package
of the source tree is installed; the packages' public names resolve."""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import inspect
import io
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from collections.abc import Set as AbstractSet
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.main import get_command

import aigem
import ngsim_graphs
from ngsim_cli.aigem import app as aigem_app
from ngsim_cli.ngsim import app as ngsim_app
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
    keys.add("max_dropped_share")  # of limits; the other limits are PhysicalLimits' own
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


def test_every_package_of_the_source_tree_is_installed(tmp_path: Path) -> None:
    """setup.py discovers the packages: a new folder with an `__init__.py` (a source's, say) is
    in the wheel without a line anywhere, and the CLI installs as ngsim_cli."""
    spec = importlib.util.spec_from_file_location("project_setup", ROOT / "setup.py")
    assert spec is not None and spec.loader is not None
    setup_module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(setup_module)  # its setup() runs only as __main__
    found = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for top in ("ngsim_graphs", "aigem")
        for init in (ROOT / top).rglob("__init__.py")
    }
    assert set(setup_module.packages(str(ROOT))) == found | {"ngsim_cli"}
    assert (
        "packages" not in tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    )
    new_source = tmp_path / "ngsim_graphs" / "sources" / "toy"
    new_source.mkdir(parents=True)
    for folder in (new_source, *new_source.parents[:2]):
        (folder / "__init__.py").touch()
    assert "ngsim_graphs.sources.toy" in setup_module.packages(str(tmp_path))


@pytest.mark.parametrize("package", [ngsim_graphs, aigem])
def test_public_names_resolve(package) -> None:  # noqa: ANN001
    for name in package.__all__:
        assert getattr(package, name) is not None, name
    assert package.__all__ == ["__version__", *package._EXPORTS]
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        package.nothing  # noqa: B018
    for name, module in package._EXPORTS.items():
        assert getattr(package, name) is getattr(importlib.import_module(module), name)
    assert dir(package) == sorted(package.__all__)  # not its imports (Any, importlib, ...)


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
        "evaluate": lambda: (
            aigem.evaluate(run, build, device_choice="cpu").samples > 0
            and aigem.evaluate(horizons, device_choice="cpu").horizons_s == (1.0, 2.0)
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


# ------------------------------------------------------------------------------------------------
# The code blocks of the README and docs/: every ```python block runs as written (in a folder laid
# out as the README's commands leave it: demo/build, demo/run), every ```bash command is checked
# (its program exists, the project's programs and scripts parse its arguments). A block that cannot
# be run says why just before it, in a comment a reader does not see: <!-- not run: REASON -->.

PAGES = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", ROOT / "data" / "README.md"] + sorted(
    (ROOT / "docs").glob("*.md")
)
FENCE = re.compile(
    r"(?:<!--\s*not run:(?P<reason>[^>]*)-->\s*\n)?^```(?P<language>\w*)\n(?P<code>.*?)^```",
    re.MULTILINE | re.DOTALL,
)


@dataclass(frozen=True)
class Block:
    """A fenced code block of a page: its language, its code and why it is not run (None: run)."""

    page: str
    line: int
    language: str
    code: str
    not_run: str | None

    def __str__(self) -> str:
        return f"{self.page}:{self.line}"


def code_blocks(language: str) -> list[Block]:
    blocks = []
    for path in PAGES:
        text = path.read_text()
        for match in FENCE.finditer(text):
            if match["language"] == language:
                line = text.count("\n", 0, match.start("language")) + 1
                reason = None if match["reason"] is None else match["reason"].strip()
                page = path.relative_to(ROOT).as_posix()
                blocks.append(Block(page, line, language, match["code"], reason))
    return blocks


def test_every_block_not_run_says_why() -> None:
    blocks = code_blocks("python") + code_blocks("bash")
    assert len(code_blocks("python")) >= 2 and len(code_blocks("bash")) >= 10
    assert [str(b) for b in blocks if b.not_run is not None and len(b.not_run) < 10] == []


def run_python(blocks: list[Block]) -> tuple[dict[str, object], str]:
    """Run the blocks one after the other in one fresh scope; (the scope, what they printed)."""
    scope: dict[str, object] = {"__name__": "docs"}
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        for block in blocks:
            code = compile("\n" * block.line + block.code, block.page, "exec")  # its own lines
            exec(code, scope)  # noqa: S102 (our own documentation)
    return scope, printed.getvalue()


@pytest.mark.parametrize("block", code_blocks("python"), ids=str)
def test_each_python_block_runs_as_written(
    block: Block, docs_demo: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A reader copies one block: it runs alone, leaning on no name another block defined."""
    if block.not_run is not None:
        pytest.skip(block.not_run)
    monkeypatch.chdir(docs_demo)
    _, printed = run_python([block])
    assert printed  # each block shows what it made


SEPARATORS = {"&&", "||", ";", "|"}
VENV_BIN = Path(sys.executable).parent  # where `.venv/bin/...` of the docs is here
PROGRAMS = {"ngsim-graphs": ngsim_app, "aigem": aigem_app}


def shell_commands(code: str) -> list[list[str]]:
    """The simple commands of a bash block as word lists: lines joined at a trailing `\\`,
    comments left out, split at &&, ||, ; and |; leading VAR=value words and `taskset -c CPUS`
    dropped."""
    commands = []
    for line in code.replace("\\\n", " ").splitlines():
        lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
        lexer.whitespace_split = True
        command: list[str] = []
        for word in [*lexer, ";"]:
            if word not in SEPARATORS:
                command.append(word)
                continue
            while command and re.fullmatch(r"[A-Z_]+=\S*", command[0]):
                command.pop(0)
            if command[:2] == ["taskset", "-c"]:
                command = command[3:]
            if command:
                commands.append(command)
            command = []
    return commands


def _made_venvs(commands: list[list[str]]) -> set[str]:
    """The folders that a block's own `python3 -m venv DIR` commands make, as written."""
    return {
        command[3].rstrip("/")
        for command in commands
        if command[0] in ("python", "python3") and command[1:3] == ["-m", "venv"]
    }


def _program(word: str, venvs: AbstractSet[str] = frozenset()) -> tuple[str, bool]:
    """(a command's program name, whether it is found: .venv/bin/X in this venv, DIR/bin/X of a
    venv the block itself makes (X as this venv has it), a script of the checkout, or a program on
    the PATH). A path outside the checkout is never found: what a machine happens to hold there is
    no part of the docs."""
    if word.startswith(".venv/bin/"):
        name = word.removeprefix(".venv/bin/")
        return name, (VENV_BIN / name).is_file()
    if "/" in word:
        folder, _, name = word.rpartition("/bin/")
        if folder in venvs:
            return name, (VENV_BIN / name).is_file()
        path = Path(word)
        inside = not path.is_absolute() and ".." not in path.parts
        return word, inside and os.access(ROOT / word, os.X_OK)
    return word, shutil.which(word) is not None or (VENV_BIN / word).is_file()


def _cli_refusal(program: str, args: list[str]) -> str | None:
    """Why the project's program refuses these arguments (parsed as it parses them, nothing run);
    None: accepted."""
    group = get_command(PROGRAMS[program])
    if not args or args[0] not in group.commands:  # type: ignore[attr-defined]
        return f"no command {args[:1]}"
    command = group.commands[args[0]]  # type: ignore[attr-defined]
    try:
        command.make_context(f"{program} {args[0]}", args[1:])
    except Exception as err:  # noqa: BLE001 (click's usage errors: the message is the point)
        return f"{type(err).__name__}: {err}"
    return None


# Runs each (script, arguments) up to its argparse parsing and stops it there: a bad option makes
# argparse exit 2 with its message on stderr; nothing of the script runs after the parsing.
PARSE_SCRIPTS = """
import argparse, json, os, runpy, sys

class Parsed(Exception):
    pass

parse = argparse.ArgumentParser.parse_known_args

def parse_and_stop(self, args=None, namespace=None):
    _, extra = parse(self, args, namespace)
    if extra:
        self.error("unrecognized arguments: " + " ".join(extra))
    raise Parsed

argparse.ArgumentParser.parse_known_args = parse_and_stop
results = []
for script, argv in json.loads(sys.argv[1]):
    sys.argv = [script, *argv]
    sys.path.insert(0, os.path.dirname(script))
    try:
        runpy.run_path(script, run_name="__main__")
        results.append("ran without parsing its arguments with argparse")
    except Parsed:
        results.append(None)
    except SystemExit as exit:
        results.append(f"exit {exit.code}")
    finally:
        sys.path.pop(0)
print(json.dumps(results))
"""


def _python_scripts(blocks: list[Block]) -> list[tuple[str, tuple[str, ...]]]:
    """Every (script, arguments) that a bash block runs with python."""
    return [
        (command[1], tuple(command[2:]))
        for block in blocks
        if block.not_run is None
        for command in shell_commands(block.code)
        if _program(command[0])[0] in ("python", "python3") and command[1].endswith(".py")
    ]


@cache
def script_refusals() -> dict[tuple[str, tuple[str, ...]], str | None]:
    """(script, arguments) -> why the script's own parser refuses them (None: accepted), for
    every python script the bash blocks run: one process for all (each imports PyTorch)."""
    calls = sorted(set(_python_scripts(code_blocks("bash"))))
    done = subprocess.run(
        [sys.executable, "-c", PARSE_SCRIPTS, json.dumps(calls)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    results = json.loads(done.stdout.splitlines()[-1])
    why = [None if r is None else f"{r}: {done.stderr.strip()}" for r in results]
    return dict(zip(calls, why, strict=True))


@cache
def help_text(*words: str) -> str:
    return subprocess.run(
        [*words, "--help"], capture_output=True, text=True, check=False, env=os.environ
    ).stdout


def command_problems(command: list[str], venvs: AbstractSet[str] = frozenset()) -> list[str]:
    """What is wrong with one command of a bash block: a program not found, arguments that the
    project's programs or scripts refuse, an option of pip or ruff that its --help does not name.
    `venvs`: the folders of the venvs that the block makes (`_made_venvs`), whose programs are
    found as this venv's and checked as the code of the block's own checkout (not parsed here)."""
    name, found = _program(command[0], venvs)
    if not found:
        return [f"{command[0]}: no such program"]
    block_made = any(command[0].startswith(f"{venv}/") for venv in venvs)
    if name in PROGRAMS and not block_made:
        refusal = _cli_refusal(name, command[1:])
        return [] if refusal is None else [f"{' '.join(command)}: {refusal}"]
    if name in ("python", "python3") and command[1].endswith(".py"):
        refusal = script_refusals()[(command[1], tuple(command[2:]))]
        return [] if refusal is None else [f"{' '.join(command)}: {refusal}"]
    if name in ("pip", "ruff"):
        text = help_text(str(VENV_BIN / name), command[1])
        options = [word.split("=")[0] for word in command[2:] if word.startswith("-")]
        return [
            f"{' '.join(command)}: {name} {command[1]} has no option {option}"
            for option in options
            if not re.search(rf"(?<![\w-]){re.escape(option)}\b", text)
        ]
    return []


@pytest.mark.parametrize("block", code_blocks("bash"), ids=str)
def test_each_bash_command_is_checked(block: Block) -> None:
    """Each command's program exists, and the project's programs and scripts accept its
    arguments as written (parsed, not run)."""
    if block.not_run is not None:
        pytest.skip(block.not_run)
    commands = shell_commands(block.code)
    assert commands
    venvs = _made_venvs(commands)
    assert [problem for command in commands for problem in command_problems(command, venvs)] == []


def test_a_program_is_found_in_the_checkout_or_the_block_never_elsewhere(tmp_path: Path) -> None:
    """A documented program outside the checkout is refused even where this machine holds it (a
    newcomer's clone does not); a venv's program is found when the block makes that venv."""
    venv_pip = tmp_path / ".venv" / "bin" / "pip"
    venv_pip.parent.mkdir(parents=True)
    venv_pip.write_text("#!/bin/sh\n")
    venv_pip.chmod(0o755)
    assert command_problems([str(venv_pip), "install", "-q", "x"]) == [
        f"{venv_pip}: no such program"
    ]
    block = "python3 -m venv bench/out/old/.venv && bench/out/old/.venv/bin/pip install -q x"
    commands = shell_commands(block)
    assert _made_venvs(commands) == {"bench/out/old/.venv"}
    assert command_problems(commands[1], _made_venvs(commands)) == []
    assert command_problems(commands[1]) == ["bench/out/old/.venv/bin/pip: no such program"]
    assert command_problems(["../elsewhere/run.sh"]) == ["../elsewhere/run.sh: no such program"]


def synopses() -> list[tuple[str, str, list[str]]]:
    """(program, command, its --options) of each usage line of the docs' plain blocks (`ngsim-graphs
    build RAW_PATH... --out DIR [--jobs N]`, continued on indented lines)."""
    found: list[tuple[str, str, list[str]]] = []
    for block in code_blocks(""):
        options = None  # those of the usage line being read
        for line in block.code.splitlines():
            usage = re.match(r"(ngsim-graphs|aigem) ([a-z-]+)", line)
            if usage:
                options = []
                found.append((usage[1], usage[2], options))
            elif not line.startswith(" "):
                options = None
            if options is not None:
                options += re.findall(r"(?<![\w-])--[\w-]+", line)
    return found


def test_each_usage_line_names_options_its_command_has() -> None:
    """The README's short tour and the docs' usage lines against each command's own options."""
    assert len(synopses()) >= 9
    unknown = []
    for program, name, options in synopses():
        command = get_command(PROGRAMS[program]).commands.get(name)  # type: ignore[attr-defined]
        known = set() if command is None else {o for p in command.params for o in p.opts}
        unknown += [f"{program} {name} {option}" for option in options if option not in known]
    assert unknown == []
