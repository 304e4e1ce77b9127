"""A split induced once and kept as a `aigem.training.resident.ResidentSplit` (docs/aigem.md).

`load_split` induces every graph of a split once (cut to the steps the model reads, scaled by
`aigem.model.data.Collate`, as the loader's batches are), CHUNK samples at a time over the loader's
worker processes, keeps only what the encoder reads and joins it into flat tensors: a sample's
nodes ordered by level, the last layer that needs the node (`aigem.model.plan.node_levels`: L at the
targets, -1 where no layer does, which are dropped), and only the edges into a node of level
>= 1 (no layer computes the others). `ResidentSplit.to` moves it to the device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from aigem.model.batch import Batch
from aigem.model.data import Collate, GraphDataset, check_covered
from aigem.model.plan import node_levels
from aigem.processes import EndWithParent
from aigem.training.capacity import edge_columns, quantities
from aigem.training.resident import EdgeTable, ResidentSplit, TargetRows, exclusive_cumsum
from ngsim_graphs.errors import NgsimError
from ngsim_graphs.layout import manifest_path

CHUNK = 256  # samples induced at a time: numpy's gathers are fastest at this size
Progress = Callable[[int, int], None]  # (samples loaded, samples in the split)


@dataclass(frozen=True)
class _Chunk:
    """The kept graphs of some samples, in the order of `ids`; node ids local to the chunk."""

    ids: np.ndarray  # (B,) the split's sample ids
    counts: np.ndarray  # (B, Q)
    x: torch.Tensor  # (n, 4)
    segment: torch.Tensor  # (n,)
    within: torch.Tensor  # (n,)
    edges: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]  # (src, dst, attr) per type
    targets: TargetRows


def _argsort(key: torch.Tensor) -> torch.Tensor:
    """torch.argsort of distinct int64 keys through numpy's, three times as fast on the CPU."""
    return torch.from_numpy(np.argsort(key.numpy()))


def _keep_nodes(batch: Batch, layers: int) -> tuple[torch.Tensor, ...]:
    """The nodes some layer reads, ordered by (sample, segment = L - level, batch order):
    their batch node ids, new id of every batch node (-1: dropped), segments, samples, levels."""
    edge_indices = [index for index, _ in batch.edge_inputs()]
    level = node_levels(len(batch.x), batch.target_node, edge_indices, layers).long()
    sample = batch.node_sample
    kept = torch.nonzero(level >= 0).squeeze(1)
    key = (sample[kept] * (layers + 1) + layers - level[kept]) * len(level) + kept
    order = kept[_argsort(key)]
    new_id = torch.full_like(level, -1)
    new_id[order] = torch.arange(len(order))
    return order, new_id, layers - level[order], sample[order], level


def _chunk(batch: Batch, ids: np.ndarray, layers: int) -> _Chunk:
    """What a split keeps of a Collate batch of samples `ids` (in the batch's order)."""
    samples, segments = len(ids), layers + 1
    order, new_id, segment, sample, level = _keep_nodes(batch, layers)
    group = sample * segments + segment  # (n,) the (sample, segment) of each kept node
    node_counts = torch.bincount(group, minlength=samples * segments)
    within = torch.arange(len(order)) - exclusive_cumsum(node_counts).index_select(0, group)
    counts, kept_edges = [node_counts.view(samples, segments)], []
    for edge_index, attr in batch.edge_inputs():
        keep = torch.nonzero(level.index_select(0, edge_index[1]) >= 1).squeeze(1)
        src = new_id.index_select(0, edge_index[0].index_select(0, keep))
        dst = new_id.index_select(0, edge_index[1].index_select(0, keep))
        by_destination = _argsort(dst * len(order) + src)  # (sample, segment, within, src)
        src, dst = src[by_destination], dst[by_destination]
        attr = attr.index_select(0, keep.index_select(0, by_destination))
        edge_group = sample.index_select(0, dst) * layers + segment.index_select(0, dst)
        counts.append(torch.bincount(edge_group, minlength=samples * layers).view(samples, layers))
        kept_edges.append((src, dst, attr))
    targets = new_id.index_select(0, batch.target_node)
    if not bool((segment.index_select(0, targets) == 0).all()) or len(targets) != int(
        node_counts.view(samples, segments)[:, 0].sum()
    ):
        raise AssertionError("the nodes of level L are not the targets")  # a plan's invariant
    return _Chunk(
        ids,
        torch.cat(counts, 1).numpy(),
        batch.x.index_select(0, order),
        segment,
        within,
        kept_edges,
        TargetRows.of(batch),
    )


def _starts(counts: np.ndarray, offset: int) -> np.ndarray:
    """(B, k) the first entry of each sample's segment, entries laid out by (sample, segment)."""
    flat = counts.reshape(-1)
    return (offset + np.cumsum(flat) - flat).reshape(counts.shape)


class _Chunks(Dataset):
    """Item i: what the split keeps of its samples i CHUNK .. (i + 1) CHUNK - 1 (a `_Chunk`)."""

    def __init__(self, dataset: GraphDataset, layers: int, check_scaler: bool) -> None:
        self.dataset, self.layers, self.check_scaler = dataset, layers, check_scaler
        self.collate = Collate(dataset.scaler)

    def __len__(self) -> int:
        return -(-len(self.dataset) // CHUNK)

    def __getitem__(self, index: int) -> _Chunk | NgsimError:
        """The chunk, or the error that its build gave (returned whole, to be raised again in
        the main process: a DataLoader raises a worker's error again as a RuntimeError holding
        its traceback, where ours is one line naming the file)."""
        first = index * CHUNK
        ids = self.dataset.batch_order(np.arange(first, min(first + CHUNK, len(self.dataset))))
        try:
            batch = self.collate(self.dataset.__getitems__(ids))
            if self.check_scaler:
                check_covered(batch, self.dataset.scaler, manifest_path(self.dataset.build_dir))
        except NgsimError as err:
            return err
        return _chunk(batch, ids, self.layers)


def _as_is(chunk: _Chunk | NgsimError) -> _Chunk | NgsimError:
    return chunk


def load_split(
    dataset: GraphDataset,
    layers: int,
    workers: int = 0,
    check_scaler: bool = False,
    progress: Progress | None = None,
) -> ResidentSplit:
    """Every graph of `dataset` (cut to the steps the model reads) induced once, over `workers`
    processes (0: in this one), and kept in host memory (`to` moves it to the device).
    `check_scaler`: refuse inputs outside the scaler's range (aigem.model.data.check_covered: a
    train split's)."""
    chunks, done = [], 0
    loader = DataLoader(
        _Chunks(dataset, layers, check_scaler),
        batch_size=None,
        num_workers=workers,
        collate_fn=_as_is,
        worker_init_fn=EndWithParent(),  # a killed fit's workers end with it
    )
    for chunk in loader:  # the workers end with the loop
        if isinstance(chunk, NgsimError):
            raise chunk
        chunks.append(chunk)
        done += len(chunk.ids)
        if progress is not None:
            progress(done, len(dataset))
    return _join(chunks, layers, len(dataset), len(dataset.config.edge_types))


def _with_spare(table: torch.Tensor) -> torch.Tensor:
    """The table and a row of zeros that no sample counts: a padded slot reads entry 0, which a
    table with no real entry (a split without one edge of a type, say) would not have."""
    return torch.cat([table, table.new_zeros((1, *table.shape[1:]))])


def _join(chunks: list[_Chunk], layers: int, samples: int, types: int) -> ResidentSplit:
    """One ResidentSplit of the chunks' samples (the split's ids 0..S-1 in any order) of a
    build of `types` edge types."""
    width = quantities(layers, types)
    counts = np.zeros((samples + 1, width), dtype=np.int64)
    node_start = np.zeros((samples + 1, layers + 1), dtype=np.int64)
    edge_start = [np.zeros((samples + 1, layers), dtype=np.int64) for _ in range(types)]
    target_start = np.zeros(samples + 1, dtype=np.int64)
    nodes = targets = 0
    edge_totals = [0] * types
    for chunk in chunks:
        counts[chunk.ids] = chunk.counts
        node_counts = chunk.counts[:, : layers + 1]
        node_start[chunk.ids] = _starts(node_counts, nodes)
        target_start[chunk.ids] = _starts(node_counts[:, :1], targets)[:, 0]
        for index in range(types):
            edge_counts = chunk.counts[:, edge_columns(layers, index)]
            edge_start[index][chunk.ids] = _starts(edge_counts, edge_totals[index])
            edge_totals[index] += int(edge_counts.sum())
        nodes, targets = nodes + len(chunk.x), targets + int(node_counts[:, 0].sum())
    offsets = np.cumsum([0] + [len(chunk.x) for chunk in chunks])[:-1]
    on = lambda parts, dtype=None: _with_spare(torch.cat(parts).to(dtype=dtype))  # noqa: E731
    node_ids = torch.int32 if nodes < 2**31 else torch.int64  # an edge's ends: half the bytes
    tables = tuple(
        EdgeTable(
            on(
                [c.edges[i][0] + offset for c, offset in zip(chunks, offsets, strict=True)],
                node_ids,
            ),
            on(
                [c.edges[i][1] + offset for c, offset in zip(chunks, offsets, strict=True)],
                node_ids,
            ),
            on([chunk.edges[i][2] for chunk in chunks]),
            torch.from_numpy(edge_start[i]),
        )
        for i in range(types)
    )
    return ResidentSplit(
        layers=layers,
        counts=counts[:samples],
        device_counts=torch.from_numpy(counts),
        x=on([chunk.x for chunk in chunks]),
        node_segment=on([chunk.segment for chunk in chunks], torch.int8),
        node_within=on([chunk.within for chunk in chunks], torch.int32),
        node_start=torch.from_numpy(node_start),
        edges=tables,
        target_start=torch.from_numpy(target_start),
        targets=TargetRows(
            *(on([getattr(chunk.targets, f.name) for chunk in chunks]) for f in fields(TargetRows))
        ),
    )
