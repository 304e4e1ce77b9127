"""The build layout: what a folder that is not a build is, said where a build is expected."""

from __future__ import annotations

import shutil
from pathlib import Path

from conftest import straight_track, write_period_csv
from highd_fixtures import two_directions
from typer.testing import CliRunner

from ngsim_graphs import layout


def _not_builds(root: Path, tiny_build: Path, tiny_run: Path) -> dict[str, tuple[Path, str]]:
    """Folders (and a file) a user may give where a build is expected, and what each is said
    to be."""
    ngsim = root / "ngsim-raw"
    write_period_csv(
        ngsim / "us-101" / "trajectories-0750am-0805am.csv", straight_track(1, range(9))
    )
    highd = root / "highd-raw"
    two_directions(highd / "data", frames=range(1, 30))
    multi = root / "multi-run"
    (multi / "h2s").mkdir(parents=True)
    (multi / "horizons.json").write_text('{"horizons_s": [2.0], "members": ["h2s"]}')
    shutil.copyfile(tiny_run / "run.json", multi / "h2s" / "run.json")
    unfinished, other, empty = root / "unfinished", root / "other", root / "empty"
    for folder in (unfinished / layout.STAGING_DIR, unfinished / layout.TRACKS_DIR, other, empty):
        folder.mkdir(parents=True)
    (other / "notes.txt").write_text("not a trajectory\n")
    raw_file = ngsim / "us-101" / "trajectories-0750am-0805am.csv"
    demo = root / "demo"  # the README's: raw files and the build made of them
    shutil.copytree(ngsim, demo / "raw")
    (demo / "build").mkdir()
    shutil.copyfile(tiny_build / layout.MANIFEST_NAME, demo / "build" / layout.MANIFEST_NAME)
    builds = root / "builds"
    for name in ("b", "a"):
        (builds / name).mkdir(parents=True)
        (builds / name / layout.MANIFEST_NAME).write_text("{}")
    run_says = f"an aigem run, not a build; its build is {tiny_build.resolve()}"
    return {
        "ngsim": (ngsim, f"holds NGSIM/highD trajectory files, not a build: build one with "
                  f"`ngsim-graphs build {ngsim} --out BUILD`"),
        "highd": (highd, f"holds NGSIM/highD trajectory files, not a build: build one with "
                  f"`ngsim-graphs build {highd} --out BUILD`"),
        "raw file": (raw_file, f"an NGSIM/highD trajectory file, not a build: build one with "
                     f"`ngsim-graphs build {raw_file} --out BUILD`"),
        "demo": (demo, f"not a build, but it holds one: give {demo / 'build'}"),
        "builds": (builds, f"not a build, but it holds builds: give one of {builds / 'a'}, "
                   f"{builds / 'b'}"),
        "run": (tiny_run, run_says),
        "multi-horizon run": (multi, run_says),
        "empty": (empty, "an empty folder, not a build"),
        "unfinished": (unfinished, "an unfinished build (interrupted?): no manifest.json"),
        "other": (other, "not a build: no manifest.json"),
    }  # fmt: skip


def test_what_a_folder_is_where_a_build_is_expected(
    tiny_build: Path, tiny_run: Path, tmp_path: Path
) -> None:
    from aigem.runs import folder as runs  # torch loads only for the tests that use it
    from ngsim_cli.aigem import app as aigem_app
    from ngsim_cli.ngsim import app as ngsim_app

    out = tmp_path / "out"
    commands = {
        "stats": (ngsim_app, ["stats", "{}"]),
        "show": (ngsim_app, ["show", "{}", "--out", f"{out}.png"]),
        "export": (ngsim_app, ["export", "{}", "--out", str(out)]),
        "verify": (ngsim_app, ["verify", "{}"]),
        "fit": (aigem_app, ["fit", "{}", "--out", str(out), "--epochs", "1", "--device", "cpu"]),
        "evaluate": (aigem_app, ["evaluate", str(tiny_run), "--data", "{}", "--device", "cpu"]),
    }
    runner = CliRunner(env={"COLUMNS": "200"})
    for kind, (path, says) in _not_builds(tmp_path, tiny_build, tiny_run).items():
        for name, (app, args) in commands.items():
            result = runner.invoke(app, [arg.format(path) for arg in args])
            assert (result.exit_code, result.stderr.strip()) == (1, f"error: {path}: {says}"), (
                kind,
                name,
                result.output,
            )
            assert not out.exists() and not Path(f"{out}.png").exists()
    assert layout.RUN_INFO_NAME == runs.RUN_INFO and layout.RUN_HORIZONS_NAME == runs.HORIZONS
