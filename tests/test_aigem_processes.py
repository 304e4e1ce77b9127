"""What a fit starts beside its own process ends with it: the loaders' workers, also when an
error stops the fit and its traceback is kept; and the decoder compiles with no pool of workers."""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
import torch._inductor.config
from torch.utils.data import DataLoader

from aigem.config import ModelConfig, TrainConfig
from aigem.data import Collate, GraphDataset
from aigem.model import AiGem
from aigem.processes import COMPILE_THREADS, compile_in_process, release_workers
from aigem.training import fit


def started_since(before: set[int]) -> set[int]:
    """The pids of this process's children alive now that were not in `before`."""
    return {child.pid for child in multiprocessing.active_children()} - before


def test_release_ends_a_loaders_persistent_workers_and_it_can_start_again(
    tiny_build: Path,
) -> None:
    dataset = GraphDataset(tiny_build, "val")
    collate = Collate(dataset.scaler)
    loader = DataLoader(
        dataset, batch_size=8, collate_fn=collate, num_workers=2, persistent_workers=True
    )
    before = {child.pid for child in multiprocessing.active_children()}
    first = sum(batch["graphs"] for batch in loader)
    assert len(started_since(before)) == 2  # persistent: alive after the pass
    release_workers(loader)
    assert started_since(before) == set()
    assert sum(batch["graphs"] for batch in loader) == first == len(dataset)
    release_workers(loader, DataLoader(dataset))  # again, and a loader without workers: no-ops
    assert started_since(before) == set()


class Stop(Exception):
    """Raised from a fit's progress callback, as `aigem paper`'s time limit is."""


def test_a_fit_stopped_by_an_error_leaves_no_worker_while_its_traceback_is_kept(
    tiny_build: Path, tmp_path: Path
) -> None:
    def progress(epoch: int, done: int, _total: int, _losses: tuple[float, ...]) -> None:
        if epoch == 2 and done == 2:  # both loaders' workers started: validation came first
            raise Stop

    before = {child.pid for child in multiprocessing.active_children()}
    train = TrainConfig(epochs=2, batch_size=16, horizon_s=1.0, workers=2, threads=1)
    with pytest.raises(Stop) as stopped:
        fit(tiny_build, tmp_path / "run", ModelConfig(), train, "cpu", progress=progress)
    # The traceback holds the loop's frames, and so the loaders (`aigem` keeps it until Python
    # handles the exit, a caller as long as it likes): their 4 workers would live on.
    assert stopped.value.__traceback__ is not None
    assert started_since(before) == set()


@pytest.fixture
def eight_compile_threads(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Inductor's compile_threads 8 in the test (TORCHINDUCTOR_COMPILE_THREADS unset), as it was
    after it (config.patch: pytest's monkeypatch would delete the setting when undone)."""
    monkeypatch.delenv(COMPILE_THREADS, raising=False)
    with torch._inductor.config.patch(compile_threads=8):
        yield


def test_compiling_happens_in_this_process_unless_the_user_says_otherwise(
    eight_compile_threads: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(COMPILE_THREADS, "8")
    compile_in_process()
    assert torch._inductor.config.compile_threads == 8
    monkeypatch.delenv(COMPILE_THREADS)
    compile_in_process()
    assert torch._inductor.config.compile_threads == 1


def test_a_fit_that_compiles_compiles_in_process(
    eight_compile_threads: None, tiny_build: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = []  # compile_threads as each model's decoder is compiled
    # Not compiled for real (on the CPU it takes a minute): what matters is the setting before.
    compile_decoder = lambda _model: settings.append(torch._inductor.config.compile_threads)
    monkeypatch.setattr(AiGem, "compile_decoder", compile_decoder)
    train = TrainConfig(epochs=1, batch_size=64, horizon_s=1.0, threads=1, compile=True)
    fit(tiny_build, tmp_path / "run", ModelConfig(), train, "cpu")
    assert settings == [1]
