"""`ngsim-graphs export-cslstm` through typer's CliRunner: the summary, the files, the errors."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from scipy.io import loadmat
from test_cli_ngsim import error_line, invoke
from test_cslstm_export import _tables, _write_six


def test_export_cslstm_writes_the_files_and_says_what_they_hold(tmp_path: Path) -> None:
    inputs = _write_six(tmp_path / "raw", _tables())
    out = tmp_path / "cslstm"
    result = invoke("export-cslstm", tmp_path / "raw", "--out", out)
    assert result.exit_code == 0, result.output
    for recording in ("us-101/0750am-0805am", "i-80/0515-0530"):
        assert recording in result.stdout
    test = loadmat(out / "TestSet.mat")
    assert (
        f"TestSet.mat: traj {len(test['traj']):,} x 47, tracks 6 x {test['tracks'].shape[1]}"
        in (result.stdout)
    )
    assert "cslstm-export.json" in result.stdout
    again = invoke("export-cslstm", *inputs, "--out", out)
    assert "holds an export already: --overwrite replaces it" in error_line(again)
    assert invoke("export-cslstm", *inputs, "--out", out, "--overwrite").exit_code == 0


def test_export_cslstm_names_a_missing_recording(tmp_path: Path) -> None:
    inputs = _write_six(tmp_path / "raw", _tables())
    result = invoke("export-cslstm", *inputs[1:], "--out", tmp_path / "out")
    assert "no rows of us-101/0750am-0805am" in error_line(result)
    assert not (tmp_path / "out").exists()
    partial = invoke("export-cslstm", *inputs[1:], "--out", tmp_path / "out", "--allow-partial")
    assert partial.exit_code == 0, partial.output
    assert "missing (--allow-partial): us-101/0750am-0805am" in partial.stdout


def _folder(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@pytest.fixture
def exported(tmp_path: Path) -> tuple[list[Path], Path]:
    inputs = _write_six(tmp_path / "raw", _tables())
    out = tmp_path / "cslstm"
    assert invoke("export-cslstm", *inputs, "--out", out).exit_code == 0
    return inputs, out


@pytest.mark.parametrize("marker", [{"files": {"TrainSet.mat": {}}}, ["TrainSet.mat"]])
def test_a_marker_that_only_names_the_files_does_not_make_them_ours(
    exported: tuple[list[Path], Path], tmp_path: Path, marker: object
) -> None:
    """A cslstm-export.json that names the files (written by hand, or by an earlier version;
    an object or not) does not give --overwrite another program's TrainSet.mat."""
    inputs, _ = exported
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "TrainSet.mat").write_bytes(b"someone else's")
    (theirs / "cslstm-export.json").write_text(json.dumps(marker))
    before = _folder(theirs)
    line = error_line(invoke("export-cslstm", *inputs, "--out", theirs, "--overwrite"))
    assert line == (
        f"error: {theirs / 'TrainSet.mat'}: was not written by export-cslstm (no "
        "cslstm-export.json of it lists its sha256): not replaced; choose another --out"
    )
    assert _folder(theirs) == before


@pytest.mark.parametrize("change", ["edited", "beside"])
def test_an_export_changed_since_is_not_replaced(
    exported: tuple[list[Path], Path], change: str
) -> None:
    inputs, out = exported
    if change == "edited":
        path = out / "ValSet.mat"
        path.write_bytes(path.read_bytes()[:-1] + b"\x00")  # the same size
    else:
        path = out / "notes.txt"
        path.write_text("mine\n")
    before = _folder(out)
    line = error_line(invoke("export-cslstm", *inputs, "--out", out, "--overwrite"))
    assert line == (
        f"error: {path}: was not written by export-cslstm (not listed in "
        f"{out / 'cslstm-export.json'}, or changed since): not replaced; move it away or choose "
        "another --out"
    )
    assert _folder(out) == before


def test_export_cslstm_never_writes_through_a_link(
    exported: tuple[list[Path], Path], tmp_path: Path
) -> None:
    inputs, out = exported
    victim = tmp_path / "mine.bin"
    victim.write_bytes(b"mine")
    os.symlink(victim, out / ".TrainSet.mat.partial")
    assert "was not written by export-cslstm" in error_line(
        invoke("export-cslstm", *inputs, "--out", out, "--overwrite")
    )
    assert victim.read_bytes() == b"mine"
    (out / ".TrainSet.mat.partial").unlink()
    again = invoke("export-cslstm", *inputs, "--out", out, "--overwrite")
    assert again.exit_code == 0, again.output
    assert victim.read_bytes() == b"mine" and sorted(p.name for p in out.iterdir()) == [
        "TestSet.mat", "TrainSet.mat", "ValSet.mat", "cslstm-export.json"
    ]  # fmt: skip
