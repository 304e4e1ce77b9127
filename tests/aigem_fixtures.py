"""A tiny synthetic build shared by the aigem tests: small graphs so that training is quick."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from aigem.runs.records import DIGESTS, RUN_INFO
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.pipeline import run_build
from ngsim_graphs.synth.formats import write_synthetic


@pytest.fixture(scope="session")
def tiny_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("aigem")
    write_synthetic(root / "raw", SynthConfig(recordings=1, minutes=0.4, seed=11))
    config = BuildConfig(d_sense_m=12.0, d_min_m=6.0)
    run_build([root / "raw"], root / "build", config)
    return root / "build"


@pytest.fixture(scope="session")
def two_recording_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("aigem2")
    write_synthetic(root / "raw", SynthConfig(recordings=2, minutes=0.3, seed=12))
    run_build([root / "raw"], root / "build", BuildConfig(d_sense_m=12.0, d_min_m=6.0))
    return root / "build"


@pytest.fixture(scope="session")
def tiny_run(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-epoch, 2 s run on the tiny build (a model to predict with, not a good one)."""
    from aigem.config import ModelConfig, TrainConfig  # torch loads only for tests that use it
    from aigem.training.fit import fit

    run = tmp_path_factory.mktemp("tiny_run") / "run"
    train = TrainConfig(epochs=1, batch_size=8, horizon_s=2.0, seed=3)
    fit(tiny_build, run, ModelConfig(), train, "cpu")
    return run


@pytest.fixture(scope="session")
def tiny_horizons_run(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-epoch 1 s + 2 s run on the tiny build (fit_horizons); RUN/h2s alone is a
    single-horizon run. Read only: a test that edits it edits a copy."""
    from aigem.config import ModelConfig, TrainConfig
    from aigem.training.fit import fit_horizons

    run = tmp_path_factory.mktemp("tiny_horizons_run") / "run"
    train = TrainConfig(epochs=1, batch_size=8, seed=3)
    fit_horizons(tiny_build, run, (1.0, 2.0), ModelConfig(), train, "cpu")
    return run


@pytest.fixture(scope="session")
def docs_demo(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder laid out as the README's commands leave it: demo/build (a tiny build), demo/run (a
    one-epoch fit on it, the README's horizon)."""
    from aigem.config import ModelConfig, TrainConfig  # torch loads only for tests that use it
    from aigem.training.fit import fit

    root = tmp_path_factory.mktemp("docs")
    (root / "demo").mkdir()
    (root / "demo" / "build").symlink_to(tiny_build, target_is_directory=True)
    fit(root / "demo" / "build", root / "demo" / "run", ModelConfig(), TrainConfig(epochs=1), "cpu")
    return root


def record_checkpoint(path: Path) -> None:
    """Have the run's run.json accept checkpoint `path` as it is now, as fit records each
    checkpoint it keeps: a test that crafts a checkpoint reaches the checks behind its sha256."""
    run_json = path.parent / RUN_INFO
    document = json.loads(run_json.read_text())
    document[DIGESTS][path.name] = [hashlib.sha256(path.read_bytes()).hexdigest()]
    run_json.write_text(json.dumps(document))
