"""`ngsim-graphs export-cslstm` through typer's CliRunner: the summary, the files, the errors."""

from __future__ import annotations

from pathlib import Path

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
