"""bench/bench_ingest.py's input: reused only when this checkout's generator made it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_ingest


def test_an_input_of_another_generator_is_made_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    made = []

    def synth(command: list[str], check: bool) -> None:  # what synth leaves: a file in its folder
        folder = Path(command[command.index("synth") + 1])
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "trajectories.txt").write_text(f"run {len(made)}\n")
        made.append(command)

    monkeypatch.setattr(subprocess, "run", synth)
    raw = tmp_path / "raw-txt-r1-m1"
    stamp = tmp_path / "raw-txt-r1-m1.generator"
    assert bench_ingest.ensure_input(raw, "txt", 1, 1.0, False) > 0 and len(made) == 1
    assert stamp.read_text() == bench_ingest.generator_digest() + "\n"
    assert bench_ingest.ensure_input(raw, "txt", 1, 1.0, False) == 0.0 and len(made) == 1
    stamp.write_text("0" * 64 + "\n")  # made by other sources of the generator
    assert bench_ingest.ensure_input(raw, "txt", 1, 1.0, False) > 0 and len(made) == 2
    assert "not made by this checkout's generator; made again" in capsys.readouterr().err
    assert stamp.read_text() == bench_ingest.generator_digest() + "\n"
    stamp.unlink()  # an input made before the digest was kept
    assert bench_ingest.ensure_input(raw, "txt", 1, 1.0, False) > 0 and len(made) == 3
    assert made[0][made[0].index("--recordings") + 1] == "1"
