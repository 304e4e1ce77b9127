"""Benchmark: AiGem training speed per batch size and device, with the operator calls and host
synchronisations of a step.

    OMP_NUM_THREADS=2 python bench/bench_train.py bench/out/graphs-txt-r6-m15
    python bench/bench_train.py BUILD --batch-sizes 32,256,1024 --device auto --workers 0 --steps 10
    python bench/bench_train.py BUILD --batch-sizes 32 --models 1,5,10   # several models a step
    python bench/bench_train.py BUILD --device cpu --batch-sizes 256 --models 5 --paths both

Devices: the CPU, then CUDA when torch.cuda.is_available() (`--device auto`; `cpu` or `cuda` for
one). Graphs are cut to the history steps the model reads (`ModelConfig().history_steps_read`), as
`aigem fit` loads them. For each batch size, graphs/s and ms a batch of:

- loader: DataLoader(GraphDataset, Collate, shuffled, --workers processes) alone, on the host,
  after its first batch (worker start-up excluded); at least --steps batches and 8,192 graphs
  (or an epoch, if less).
- model step: fit's one training step (aigem.training.trainers: a model alone is an ensemble of one;
  zero_grad, forward, the masked loss, backward, Adam's step) on batches loaded beforehand and
  already on the device (no loading, no host-to-device copy): --warmup steps, then --steps timed
  (CUDA synchronised at both ends).
- M models (--models): the step of M models of horizons 1..5 s (the k-th model's is 1 + k % 5
  s) as `aigem fit --horizon-s` trains them, as one ensemble (aigem.training.ensemble: the members'
  losses summed, one backward, one fused Adam); `M apart`: the same M models stepped one after
  the other, each an ensemble of one with its own optimizer. graphs/s counts a graph once,
  through all of them.
- fit loop: `aigem.training.fit.fit` itself (1 epoch at this batch size, --workers, a temporary run
  directory) watched through its `progress` callback: the clock starts at the report of batch
  --warmup and stops at the first report --steps batches later; the profiler then watches
  --profile-steps batches, and the callback raises to end fit. So it is fit's own loop in steady
  state (loading, host-to-device copy, step, its loss checks and read-outs, bookkeeping) without
  start-up or validation, which a full epoch of 89,000 graphs would take minutes to reach. The
  windows count the batches that fit reports done, so they hold if fit reports less often.
- fit M h (for each M of --models from 2 to 5): the same for `aigem.training.fit.fit_horizons` with
  the horizons 1..M s, its M models trained as one ensemble.
- to device (once per device, where static batches are measured): the train split loaded onto
  the device (aigem.training.loading: induced over --workers processes, what a layer reads kept);
  graphs/s of the loading, its seconds in ms/batch.
- static M (1 and each M of --models): the same step of M models (horizons 1..5 s) as one
  ensemble on static batches of the split on the device (aigem.training.engine): assembled there by
  index, padded to the capacity tiers of aigem.training.capacity, on CUDA captured once per tier and
  replayed. `padding`:
  the share of the tier-0 capacity that padding fills; `GPU GB`: the memory PyTorch reserved on
  the GPU so far (the splits, the captured steps' pools).
- fit loop st, fit M h st: fit's loop on static batches (`TrainConfig.resident`), CUDA's
  default; `--paths both` measures each device's fit loop on both kinds of batches.

Per step, over --profile-steps untimed steps after the timed ones (torch.profiler with
ProfilerActivity.CPU, plus CUDA on a GPU, and a TorchFunctionMode), divided by the steps:

- ops/step: aten operators dispatched: CPU events named `aten::*` with no `aten::*` ancestor, i.e.
  the calls made by Python code, by autograd nodes and by the optimizer; an operator's own
  sub-operators are not counted again. The fit loop adds its own (copies to the device, loss
  checks, and the collate's with 0 workers or the rebuilding of the workers' tensors).
- syncs/step: operations that make the host wait for a GPU (on the CPU: that would on a GPU):
  profiler events `aten::_local_scalar_dense` (under .item(), int(), float(), bool() of a tensor,
  `if torch.isfinite(loss)`, repeat_interleave without output_size), `aten::nonzero` (boolean
  indexing too), `aten::bincount`, `aten::_unique`, `aten::_unique2`, `aten::unique_dim`,
  `aten::unique_consecutive`, `aten::masked_select`, `aten::equal`, each counted once (not again
  inside another), none inside Adam's step (its .item() reads its step counter, a CPU tensor);
  and, from the TorchFunctionMode, `Tensor.tolist()` (which the profiler does not show on the CPU)
  and `.cpu()` / `.to()` of a device tensor to the CPU. The last column names them. On the CPU the
  CPU code path is counted: the model's CSR aggregation, used on the CPU only, adds its own.
- kernels/step (CUDA only): CUDA kernel events (memcpy and memset excluded), replayed ones too.
- launches/step (CUDA only): what the host dispatched: cudaLaunchKernel and cudaGraphLaunch
  runtime calls (a replayed CUDA graph is one).
- cuda syncs/step (CUDA only): cudaStreamSynchronize, cudaEventSynchronize and cudaMemcpy runtime
  calls (not cudaDeviceSynchronize, which the profiler calls when it stops).

`threads` is torch's intra-op thread count after the measurement (fit may set it). Kineto writes
`profiler_start` / `profiler_stop` lines to stderr.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
from torch.overrides import TorchFunctionMode
from torch.profiler import ProfilerActivity
from torch.utils.data import DataLoader

from aigem.config import ModelConfig, TrainConfig
from aigem.model import plan as aigem_plan
from aigem.model.batch import Batch
from aigem.model.data import Collate, GraphDataset
from aigem.model.network import AiGem
from aigem.training import capacity
from aigem.training.engine import epoch_batches
from aigem.training.fit import fit_horizons, make_optimizer
from aigem.training.loading import load_split
from aigem.training.resident import ResidentSplit
from aigem.training.trainers import Trainer, stack_trainer

LOADER_GRAPHS = 8192  # the loader is fast: fewer graphs would time noise
SYNC_OPS = {
    "aten::_local_scalar_dense",
    "aten::nonzero",
    "aten::bincount",
    "aten::_unique",
    "aten::_unique2",
    "aten::unique_dim",
    "aten::unique_consecutive",
    "aten::masked_select",
    "aten::equal",
}
CUDA_SYNCS = {"cudaStreamSynchronize", "cudaEventSynchronize", "cudaMemcpy"}
LAUNCHES = ("cudaLaunchKernel", "cudaGraphLaunch", "cuLaunchKernel")  # what the host dispatches
COLUMNS = {
    "graphs/s": 9,
    "ms/batch": 8,
    "ops/step": 8,
    "syncs/step": 10,
    "kernels/step": 12,
    "launches/step": 13,
    "cuda syncs/step": 15,
    "threads": 7,
    "padding": 7,
    "GPU GB": 6,
    "syncs by op (per step)": 0,
}


class _Conversions(TorchFunctionMode):
    """Counts the copies to host memory that the profiler does not show as such."""

    def __init__(self) -> None:
        super().__init__()
        self.names: Counter[str] = Counter()

    def __torch_function__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        name = getattr(func, "__name__", "")
        if name == "tolist":
            self.names["tolist"] += 1
        elif (
            name in ("cpu", "to")
            and isinstance(out, torch.Tensor)
            and out.device.type == "cpu"
            and isinstance(args[0], torch.Tensor)
            and args[0].device.type != "cpu"
        ):
            self.names[f"{name} (to host)"] += 1
        return out


class _Counts:
    """The profiler and the conversion counter over a window of steps (see the docstring)."""

    def __init__(self, device: torch.device, conversions: bool = True) -> None:
        self.cuda = device.type == "cuda"
        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if self.cuda else [])
        self.profiler = torch.profiler.profile(activities=activities)
        # A TorchFunctionMode makes compiled code compile again under it: not for compiled steps
        self.conversions = _Conversions() if conversions else None

    def start(self) -> None:
        self.profiler.start()
        if self.conversions is not None:
            self.conversions.__enter__()

    def stop(self) -> None:
        if self.conversions is not None:
            self.conversions.__exit__(None, None, None)
        self.profiler.stop()

    def per_step(self, steps: int) -> dict[str, object]:
        syncs = Counter(self.conversions.names if self.conversions is not None else {})
        ops, kernels, launches, cuda_syncs = 0, 0, 0, 0
        for event in self.profiler.events():
            name, ancestors, parent = event.name, [], event.cpu_parent
            while parent is not None:
                ancestors.append(parent.name)
                parent = parent.cpu_parent
            if event.device_type == torch.autograd.DeviceType.CUDA:
                kernels += not name.startswith(("Memcpy", "Memset"))
            elif name in CUDA_SYNCS:
                cuda_syncs += 1
            elif name.startswith(LAUNCHES):
                launches += 1
            elif name.startswith("aten::") and not any(a.startswith("aten::") for a in ancestors):
                ops += 1
            if name in SYNC_OPS and not any(
                a in SYNC_OPS or a.startswith("Optimizer.step#") for a in ancestors
            ):
                syncs[name.removeprefix("aten::")] += 1
        by_op = ", ".join(f"{name} {count / steps:g}" for name, count in syncs.most_common())
        row = {
            "ops/step": ops / steps,
            "syncs/step": sum(syncs.values()) / steps,
            "syncs by op (per step)": by_op or "none",
        }
        if self.cuda:
            row |= {
                "kernels/step": kernels / steps,
                "launches/step": launches / steps,
                "cuda syncs/step": cuda_syncs / steps,
            }
        return row


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _endless(loader: DataLoader) -> Iterator[Batch]:
    while True:
        yield from loader


def measure_loader(
    dataset: GraphDataset, batch_size: int, workers: int, timed: int, keep: int
) -> tuple[float, list[Batch]]:
    """(graphs/s over `timed` batches after the first, `keep` batches for the model step)."""
    collate = Collate(dataset.scaler, layers=ModelConfig().layers)  # as fit: with the plan
    loader = DataLoader(
        dataset, batch_size=batch_size, shuffle=True, num_workers=workers, collate_fn=collate
    )
    batches = _endless(loader)
    next(batches)  # workers start, first batch
    kept: list[Batch] = []
    start = time.perf_counter()
    for _ in range(timed):
        batch = next(batches)
        if len(kept) < keep:
            kept.append(batch)
    rate = timed * batch_size / (time.perf_counter() - start)
    return rate, kept + [next(batches) for _ in range(keep - len(kept))]


def measure_step(
    batches: list[Batch],
    dataset: GraphDataset,
    device: torch.device,
    args: argparse.Namespace,
    compiled: bool = False,
    models: int = 1,
    together: bool = True,
) -> dict[str, object]:
    """The model step alone on prepared batches: --warmup, --steps timed, --profile-steps counted.
    `compiled`: the decoder through torch.compile (compiled in the warm-up steps). `models`: that
    many models of horizons 1..5 s (the k-th model's is 1 + k % 5 s), as one ensemble
    (`together`) or one after the other, each with its own optimizer; graphs/s counts a graph
    once, through all of them."""
    torch.manual_seed(0)
    nets = [AiGem(ModelConfig()).to(device) for _ in range(models)]
    if compiled:
        for net in nets:
            net.compile_decoder()
    optimizers = [make_optimizer(net, TrainConfig(), device) for net in nets]
    step_s = dataset.config.time_step_s
    horizons = sorted(  # fit's default horizon for one model; 1..5 s for several
        TrainConfig().horizon_steps(step_s) if models == 1 else round((1 + k % 5) / step_s)
        for k in range(models)
    )
    on_device = [batch.to(device, non_blocking=True) for batch in batches]
    groups = [range(models)] if together else [[k] for k in range(models)]
    trainers = [_trainer(nets, optimizers, horizons, group, dataset, device) for group in groups]

    def step(batch: Batch) -> None:
        for trainer in trainers:
            trainer.step(batch, 1e-3)

    warmup = on_device[: args.warmup] * (4 if compiled else 1)  # compiles a few variants first
    timed = on_device[args.warmup : args.warmup + args.steps]
    for batch in warmup:
        step(batch)
    _sync(device)
    start = time.perf_counter()
    for batch in timed:
        step(batch)
    _sync(device)
    seconds = time.perf_counter() - start
    counts = _Counts(device, conversions=not compiled)
    counts.start()
    for batch in on_device[args.warmup + args.steps :]:
        step(batch)
    counts.stop()
    graphs = sum(batch.graphs for batch in timed)  # a short batch: fewer
    return {
        "graphs/s": graphs / seconds,
        "ms/batch": 1000 * seconds / len(timed),
        **counts.per_step(args.profile_steps),
    }


def _trainer(
    nets: list[AiGem],
    optimizers: list[torch.optim.Optimizer],
    horizons: list[int],
    group: range | list[int],
    dataset: GraphDataset,
    device: torch.device,
) -> Trainer:
    """The models `group` of `nets` (their steps `horizons`) stacked as fit's trainer."""
    picked = [nets[k] for k in group], [optimizers[k] for k in group], [horizons[k] for k in group]
    return stack_trainer(*picked, dataset.scaler, None, device)


def load_resident(dataset: GraphDataset, device: torch.device, workers: int):  # noqa: ANN201
    """The train split on `device` (aigem.training.resident) and the row of its loading: graphs/s."""
    start = time.perf_counter()
    split = load_split(dataset, ModelConfig().layers, workers, check_scaler=True).to(device)
    _sync(device)
    seconds = time.perf_counter() - start
    return split, {"graphs/s": len(dataset) / seconds, "ms/batch": 1000 * seconds}


def measure_static(
    split: ResidentSplit,
    dataset: GraphDataset,
    batch_size: int,
    device: torch.device,
    args: argparse.Namespace,
    models: int,
) -> dict[str, object]:
    """The step of aigem.training.engine on static batches of the split on the device (assembled by index,
    forward, backward, Adam; on CUDA captured per capacity tier and replayed) of `models` models
    of horizons 1..5 s as one ensemble: --warmup, --steps timed, --profile-steps counted."""
    torch.manual_seed(0)
    nets = [AiGem(ModelConfig()).to(device) for _ in range(models)]
    step_s = dataset.config.time_step_s
    horizons = sorted(
        TrainConfig().horizon_steps(step_s) if models == 1 else round((1 + k % 5) / step_s)
        for k in range(models)
    )
    optimizers = [make_optimizer(net, TrainConfig(), device) for net in nets]
    trainer = stack_trainer(
        nets, optimizers, horizons, dataset.scaler, None, device, device.type == "cuda"
    )
    base = capacity.base_capacity(split.counts, batch_size, split.layers)
    order = np.random.default_rng(0).permutation(split.samples)
    batches = epoch_batches(split, order, batch_size, base, dataset.batch_order, device)
    needed = args.warmup + args.steps + args.profile_steps
    if len(batches) < needed + 1:
        return {}
    step = lambda i: trainer.step(batches[i], 1e-3)  # noqa: E731
    for index in range(args.warmup):
        step(index)
    _sync(device)
    start = time.perf_counter()
    for index in range(args.warmup, args.warmup + args.steps):
        step(index)
    _sync(device)
    seconds = time.perf_counter() - start
    counts = _Counts(device)
    counts.start()
    for index in range(args.warmup + args.steps, needed):
        step(index)
    _sync(device)
    counts.stop()
    graphs = sum(batches.graphs[args.warmup : args.warmup + args.steps])
    padding = 1 - float(split.counts[order[: batch_size * 8]].sum()) / (8 * sum(base.sizes))
    memory = (
        {"GPU GB": torch.cuda.max_memory_reserved(device) / 1e9} if device.type == "cuda" else {}
    )
    return {
        "graphs/s": graphs / seconds,
        "ms/batch": 1000 * seconds / args.steps,
        "padding": f"{padding:.0%}",
        **memory,
        **counts.per_step(args.profile_steps),
    }


class _Enough(Exception):
    """Raised from fit's progress callback once the probe has what it needs."""


class _FitProbe:
    """fit's progress callback: times --steps batches after --warmup, then counts the next ones."""

    def __init__(self, device: torch.device, args: argparse.Namespace) -> None:
        self.device, self.args, self.counts = device, args, _Counts(device)
        self.clock: tuple[int, float] | None = None  # (batches done, time) when timing began
        self.timed: tuple[int, float] | None = None  # (batches, seconds)
        self.profiled_from: int | None = None  # batches done when profiling began
        self.profiled = 0  # batches profiled, once done

    def __call__(self, epoch: int, done: int, total: int, losses: object) -> None:
        if self.clock is None and done >= self.args.warmup:
            _sync(self.device)
            self.clock = (done, time.perf_counter())
        elif self.timed is None and self.clock and done >= self.clock[0] + self.args.steps:
            _sync(self.device)
            self.timed = (done - self.clock[0], time.perf_counter() - self.clock[1])
            self.profiled_from = done
            self.counts.start()
        elif (
            self.profiled_from is not None and done >= self.profiled_from + self.args.profile_steps
        ):
            self.counts.stop()
            self.profiled = done - self.profiled_from
            raise _Enough


def measure_fit(
    build: Path,
    batch_size: int,
    device: torch.device,
    args: argparse.Namespace,
    horizons_s: tuple[float, ...],
    resident: bool | None = None,
) -> dict[str, object]:
    """The whole fit loop at this batch size (see the docstring), of the fit of `horizons_s`
    (one model per horizon), on the loader's batches or static ones (`resident`,
    None: fit's default for the device); empty where the epoch ran out."""
    probe = _FitProbe(device, args)
    train = TrainConfig(
        epochs=1,
        batch_size=batch_size,
        workers=args.workers,
        seed=0,
        threads=torch.get_num_threads(),
        resident=resident,
    )
    with tempfile.TemporaryDirectory() as tmp:
        try:
            run = Path(tmp) / "run"
            fit_horizons(build, run, horizons_s, ModelConfig(), train, device.type, progress=probe)
        except _Enough:
            pass
        finally:
            if probe.profiled_from is not None and not probe.profiled:
                probe.counts.stop()  # the epoch ended inside the profiled window
    row: dict[str, object] = {}
    if probe.timed is not None:
        batches, seconds = probe.timed
        row |= {"graphs/s": batches * batch_size / seconds, "ms/batch": 1000 * seconds / batches}
    return row | (probe.counts.per_step(probe.profiled) if probe.profiled else {})


def describe_machine(devices: list[torch.device]) -> str:
    cpuinfo = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    names = [
        line.split(":", 1)[1].strip()
        for line in cpuinfo.splitlines()
        if line.startswith("model name")
    ]
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    cuda = [torch.cuda.get_device_name(device) for device in devices if device.type == "cuda"]
    return (
        f"machine: {names[0] if names else platform.machine()}, {os.cpu_count()} CPUs "
        f"({usable} usable), torch {torch.__version__}, {torch.get_num_threads()} intra-op "
        f"threads (OMP_NUM_THREADS {os.environ.get('OMP_NUM_THREADS', 'unset')})"
        + (f"; cuda: {cuda[0]}" if cuda else "")
    )


def _row(device: str, size: object, what: str, row: dict[str, object]) -> None:
    """One line of the table; `row` maps COLUMNS to values (absent: "-")."""
    cells = [f"{device:<6}", f"{size!s:<5}", f"{what:<10}"]
    for column, width in COLUMNS.items():
        value = row.get(column, "-")
        cells.append((f"{value:,.1f}" if isinstance(value, float) else str(value)).rjust(width))
    print("  ".join(cells).rstrip())


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("build", type=Path)
    parser.add_argument("--batch-sizes", default="32,256,1024")
    parser.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default="auto",
        help="auto: the CPU, then CUDA when present",
    )
    parser.add_argument("--workers", type=int, default=0, help="DataLoader worker processes")
    parser.add_argument("--steps", type=int, default=10, help="timed batches per measurement")
    parser.add_argument(
        "--warmup",
        type=int,
        default=4,
        help="untimed steps first (on CUDA a static step is captured at its third call)",
    )
    parser.add_argument("--profile-steps", type=int, default=2, help="steps the profiler counts")
    parser.add_argument(
        "--models",
        default="1",
        help="comma-separated numbers of models stepped on each batch (e.g. 1,5,10: the model "
        "step of several models as one ensemble, as a multi-horizon fit trains them, and one "
        "after the other; and for 2 to 5 models a multi-horizon fit's loop)",
    )
    parser.add_argument(
        "--paths",
        choices=("default", "both"),
        default="default",
        help="the fit loop on the device's default batches only (CUDA: static, the CPU: the "
        "loader's), or on both: static batches (rows 'static', 'fit static') and the loader's",
    )
    parser.add_argument(
        "--compile",
        action="store_true",
        help="also the step with the decoder compiled (a minute or two to compile on the CPU)",
    )
    args = parser.parse_args()
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA device is available")
    auto = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    devices = [torch.device(name) for name in (auto if args.device == "auto" else [args.device])]
    read = ModelConfig().history_steps_read
    dataset = GraphDataset(args.build, "train", history_steps=read)
    print(describe_machine(devices))
    print(
        f"build {args.build}: {len(dataset):,} train samples, graphs cut to {read} history "
        f"steps; {args.workers} loader workers; {args.warmup} warm-up, {args.steps} timed, "
        f"{args.profile_steps} profiled steps\n"
    )
    _row("device", "batch", "measured", {column: column for column in COLUMNS})
    several = [int(n) for n in args.models.split(",") if int(n) > 1]
    residents = {}
    for device in devices:
        if device.type == "cuda" or args.paths == "both":
            residents[device], row = load_resident(dataset, device, args.workers)
            _row(device.type, "-", "to device", row)
    for size in (int(size) for size in args.batch_sizes.split(",")):
        timed = max(args.steps, math.ceil(min(LOADER_GRAPHS, len(dataset)) / size))
        keep = args.warmup + args.steps + args.profile_steps
        rate, batches = measure_loader(dataset, size, args.workers, timed, keep)
        threads = {"threads": torch.get_num_threads()}
        _row("host", size, "loader", {"graphs/s": rate, "ms/batch": 1000 * size / rate, **threads})
        for device in devices:
            _measure_device(device, size, batches, dataset, residents.get(device), several, args)


def _measure_device(
    device: torch.device,
    size: int,
    batches: list[Batch],
    dataset: GraphDataset,
    split: ResidentSplit | None,
    several: list[int],
    args: argparse.Namespace,
) -> None:
    """The rows of one device at one batch size (see the docstring)."""
    row = lambda what, values: _row(  # noqa: E731
        device.type, size, what, values | {"threads": torch.get_num_threads()}
    )
    row("model step", measure_step(batches, dataset, device, args))
    if device.type == "cpu":  # the accelerator's aggregation, run on the CPU
        aigem_plan.CPU_SPARSE = False
        row("gpu path", measure_step(batches, dataset, device, args))
        aigem_plan.CPU_SPARSE = True
    for models in several:
        for together, what in ((True, "models"), (False, "apart")):
            values = measure_step(batches, dataset, device, args, models=models, together=together)
            row(f"{models} {what}", values)
    if args.compile:
        row("compiled", measure_step(batches, dataset, device, args, compiled=True))
    if split is not None:
        for models in [1, *several]:
            row(f"static {models}", measure_static(split, dataset, size, device, args, models))
    paths = {"cuda": (True, False), "cpu": (False, True)}[device.type]
    for resident in paths if args.paths == "both" else paths[:1]:
        label = " st" if resident else ""
        row(
            f"fit loop{label}",
            measure_fit(args.build, size, device, args, (TrainConfig().horizon_s,), resident),
        )
        for models in (m for m in several if m <= 5):
            horizons = tuple(float(h) for h in range(1, models + 1))
            values = measure_fit(args.build, size, device, args, horizons, resident)
            row(f"fit {models} h{label}", values)


if __name__ == "__main__":
    main()
