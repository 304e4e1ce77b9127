"""A tiny synthetic build shared by the aigem tests: small graphs so that training is quick."""

from __future__ import annotations

from pathlib import Path

import pytest

from ngsim_graphs.building import run_build
from ngsim_graphs.config import BuildConfig, SynthConfig
from ngsim_graphs.synthesis import write_synthetic


@pytest.fixture(scope="session")
def tiny_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("aigem")
    write_synthetic(root / "raw", SynthConfig(recordings=1, minutes=0.4, seed=11))
    config = BuildConfig(d_sense_m=12.0, d_min_m=6.0)
    run_build([root / "raw"], root / "build", config)
    return root / "build"
