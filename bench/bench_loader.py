"""Benchmark: is the data loader ever what limits AiGem's training?

Prints graphs per second of (1) the memory-mapped dataset with its collate (read + induce +
collate), with 0 and 2 worker processes, for whole graphs (all K_H history steps) and for the
graphs as `aigem fit` loads them (the L + 1 steps the model reads; the model's output is the
same); (2) the natural alternative, a list of PyTorch Geometric HeteroData objects batched by
PyG's own DataLoader (only the batching is timed: the list is made first); (3) AiGem training
(forward, backward, Adam step) on the CPU; and the ratios.

    python bench/bench_loader.py bench/out/graphs-txt-r6-m15
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from aigem.config import ModelConfig, TrainConfig
from aigem.model.data import Collate, GraphDataset
from aigem.model.network import AiGem
from aigem.training.fit import make_optimizer
from aigem.training.trainers import stack_trainer


def graphs_per_second(loader: DataLoader, batches: int, batch_size: int) -> float:
    iterator = iter(loader)
    next(iterator)  # workers start, first batch
    start = time.perf_counter()
    for _ in range(batches):
        next(iterator)
    return batches * batch_size / (time.perf_counter() - start)


def pyg_baseline(dataset: GraphDataset, n_graphs: int, batch_size: int) -> tuple[float, float]:
    """(graphs/s of PyG's DataLoader over a prepared list of HeteroData, bytes per graph held)."""
    from torch_geometric.loader import DataLoader as PygLoader

    from aigem.model.pyg import to_hetero_data

    graphs = [to_hetero_data(dataset[i], dataset.scaler, sample_id=i) for i in range(n_graphs)]
    held = sum(
        v.nbytes for g in graphs for store in g.stores for v in store.values() if torch.is_tensor(v)
    )
    start = time.perf_counter()
    for _ in PygLoader(graphs, batch_size=batch_size, shuffle=True):
        pass
    return n_graphs / (time.perf_counter() - start), held / n_graphs


def training_graphs_per_second(dataset: GraphDataset, batches: int, batch_size: int) -> float:
    """fit's one training step (aigem.training.trainers) of a model alone on the CPU."""
    torch.manual_seed(0)
    model, cpu = AiGem(ModelConfig()), torch.device("cpu")
    optimizer = make_optimizer(model, TrainConfig(), cpu)
    steps = model.config.future_steps
    trainer = stack_trainer([model], [optimizer], [steps], dataset.scaler, None, cpu)
    loader = DataLoader(
        dataset, batch_size=batch_size, shuffle=True, collate_fn=Collate(dataset.scaler)
    )
    data = [
        b for _, b in zip(range(batches + 1), loader, strict=False)
    ]  # loading is not timed here
    start = None
    for index, batch in enumerate(data):
        if index == 1:
            start = time.perf_counter()
        trainer.step(batch, 1e-3)
    return batches * batch_size / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("build", type=Path)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--batches", type=int, default=40)
    parser.add_argument("--train-batches", type=int, default=5)
    args = parser.parse_args()

    start = time.perf_counter()
    whole = GraphDataset(args.build, "train")
    open_ms = 1000 * (time.perf_counter() - start)
    read = ModelConfig().history_steps_read
    as_fit = GraphDataset(args.build, "train", history_steps=read)
    kw = {"batch_size": args.batch_size, "shuffle": True, "collate_fn": Collate(whole.scaler)}
    rates = {
        (name, w): graphs_per_second(
            DataLoader(data, num_workers=w, **kw), args.batches, args.batch_size
        )
        for name, data in (("whole", whole), ("fit", as_fit))
        for w in (0, 2)
    }
    pyg, pyg_bytes = pyg_baseline(whole, args.batches * args.batch_size, args.batch_size)
    train = training_graphs_per_second(as_fit, args.train_batches, args.batch_size)
    k_h, size = whole.config.history_steps, args.batch_size
    print(f"build {args.build}: {len(whole):,} train samples, opened in {open_ms:.0f} ms")
    for name, label in (
        ("whole", f"whole graphs, {k_h} steps"),
        ("fit", f"as aigem fit, {read} steps"),
    ):
        for w in (0, 2):
            _row(
                f"loader, {label}, {w} workers",
                rates[name, w],
                "graphs/s (read + induce + collate)",
            )
    _row("PyG list of HeteroData, whole", pyg, "graphs/s (PyG DataLoader; batching only)")
    _row(
        "  that list holds",
        pyg_bytes / 1e3,
        f"kB a graph: {pyg_bytes * len(whole) / 1e9:,.1f} GB for train",
    )
    _row("training (CPU)", train, f"graphs/s (forward + backward + Adam, batch {size})")
    _row("loader / training, 0 workers", rates["fit", 0] / train, "x")
    _row("loader / training, 2 workers", rates["fit", 2] / train, "x")
    _row("ours / PyG, whole, 0 workers", rates["whole", 0] / pyg, "x", digits=2)


def _row(label: str, value: float, unit: str, digits: int = 1) -> None:
    print(f"{label:<40} {value:10,.{digits}f} {unit}")


if __name__ == "__main__":
    main()
