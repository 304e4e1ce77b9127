"""What a fit starts beside its own process ends with it: the loaders' workers, also when an
error stops the fit and its traceback is kept; and the decoder compiles with no pool of workers."""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
import torch._inductor.config
from torch.utils.data import DataLoader

from aigem.config import ModelConfig, TrainConfig
from aigem.model.data import Collate, GraphDataset
from aigem.model.network import AiGem
from aigem.processes import COMPILE_THREADS, EndWithParent, compile_in_process, release_workers
from aigem.training import loading
from aigem.training.fit import _loaders, fit


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
    first = sum(batch.graphs for batch in loader)
    assert len(started_since(before)) == 2  # persistent: alive after the pass
    release_workers(loader)
    assert started_since(before) == set()
    assert sum(batch.graphs for batch in loader) == first == len(dataset)
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


LINUX = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux's")
PR_GET_PDEATHSIG = 2  # <linux/prctl.h>


def _in_a_child(ask: EndWithParent) -> int:
    """The exit status of a forked child that runs `ask` as a worker would, then exits with the
    signal the kernel will send it when its parent ends (prctl(PR_GET_PDEATHSIG))."""
    pid = os.fork()
    if pid == 0:  # the child: nothing but these calls, then out
        ask(0)
        death_signal = ctypes.c_int()
        ctypes.CDLL(None).prctl(PR_GET_PDEATHSIG, ctypes.byref(death_signal), 0, 0, 0)
        os._exit(death_signal.value)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status)


@LINUX
def test_a_worker_asks_to_be_killed_with_its_parent() -> None:
    assert _in_a_child(EndWithParent()) == signal.SIGKILL
    orphan = EndWithParent()
    orphan.parent_pid = -1  # a parent that ended before its worker asked: it ends at once
    assert _in_a_child(orphan) == 1


def test_the_fits_loaders_and_the_splits_loading_end_their_workers_with_the_fit(
    tiny_build: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    train = TrainConfig(batch_size=8, workers=1)
    _, train_loader, val_loader, *_ = _loaders(
        tiny_build, ModelConfig(), train, 0, 1, torch.device("cpu"), 1
    )
    assert isinstance(train_loader.worker_init_fn, EndWithParent)
    assert isinstance(val_loader.worker_init_fn, EndWithParent)
    made = []  # the keyword arguments of load_split's loader
    loader = lambda *args, **kwargs: made.append(kwargs) or DataLoader(*args, **kwargs)
    monkeypatch.setattr(loading, "DataLoader", loader)
    loading.load_split(GraphDataset(tiny_build, "val"), layers=2, workers=0)
    assert isinstance(made[0]["worker_init_fn"], EndWithParent)


def _ended(pid: int) -> bool:
    """Whether process `pid` has ended (gone, or a zombie that nobody has reaped yet)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] in ("Z", "X")


KILLED_FIT = """
import multiprocessing, sys, time
from pathlib import Path
import torch
from aigem.training import resident
from aigem.config import ModelConfig, TrainConfig
from aigem.training.fit import _loaders
train = TrainConfig(batch_size=8, workers=1)
_, loader, *_ = _loaders(Path(sys.argv[1]), ModelConfig(), train, 0, 1, torch.device("cpu"), 1)
next(iter(loader))
print(*(child.pid for child in multiprocessing.active_children()), flush=True)
time.sleep(600)
"""


@LINUX
@pytest.mark.slow  # importing PyTorch in a new process: seconds
def test_a_fits_loader_worker_ends_with_a_kill_9_of_the_fit(tiny_build: Path) -> None:
    command = [sys.executable, "-c", KILLED_FIT, str(tiny_build)]
    fit_process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    try:
        workers = [int(pid) for pid in fit_process.stdout.readline().split()]
    finally:
        fit_process.kill()  # kill -9, as the out-of-memory killer does
        fit_process.wait()
    assert len(workers) == 1
    deadline = time.monotonic() + 2.0  # PyTorch's own check would take up to 5 s
    while not all(map(_ended, workers)):
        assert time.monotonic() < deadline, f"worker {workers} alive 2 s after kill -9"
        time.sleep(0.02)
