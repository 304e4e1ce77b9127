"""A split on the device, and static batches assembled there by index (docs/aigem.md).

`load_split` induces every graph of a split once (cut to the steps the model reads, scaled by
`aigem.data.Collate`, as the loader's batches are), keeps only what the encoder reads and stores
it as flat tensors on the device. A sample's nodes are ordered by level, the last layer that
needs the node (`aigem.plan.node_levels`: L at the targets, -1 where no layer does, which are
dropped), and only the edges into a node of level >= 1 are kept (no layer computes the others).

`ResidentSplit.batch(ids, capacity)` assembles the graphs of the samples `ids` on the device in
the layout of `aigem.capacity`: node segment k holds every sample's nodes of level L - k, in the
order of `ids`, padded to the capacity, then one spare node, the segment's sink; edge segment k of
a type holds its edges into segment k's nodes, by destination (a CSR order), padded with edges
from the sink to the sink. So layer l reads a prefix of the nodes and computes a shorter prefix,
from a prefix of each type's edges (an `aigem.plan.Plan` with no reordering), and the targets
are the first nodes. Padding changes no number: a padded node has no edge into a real one and
no feature, a padded edge joins a sink (which no real node reads) to itself, and a padded target
is masked in every loss and metric. Every size is known on the host before the batch is made,
and the assembly reads nothing back: a step over it never waits for the device.
"""

from __future__ import annotations

import gc
from collections.abc import Callable
from dataclasses import dataclass, field, fields

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from aigem.batch import Batch
from aigem.capacity import Capacity, edge_columns, quantities
from aigem.data import Collate, GraphDataset, check_covered
from aigem.plan import Adjacency, Plan, node_levels
from aigem.processes import EndWithParent
from ngsim_graphs.errors import NgsimError
from ngsim_graphs.layout import manifest_path

CHUNK = 256  # samples induced at a time: numpy's gathers are fastest at this size
DEVICE_SHARE = 0.5  # of a GPU's free memory the splits may take: the rest for the steps
Progress = Callable[[int, int], None]  # (samples loaded, samples in the split)


def _exclusive_cumsum(counts: torch.Tensor) -> torch.Tensor:
    return counts.cumsum(-1) - counts


def _runs(
    starts: torch.Tensor, lengths: torch.Tensor, begins: torch.Tensor, size: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Runs of entries copied into `size` slots: run r's `lengths[r]` entries from `starts[r]`
    go to the slots from `begins[r]` (non-decreasing; runs do not overlap). Returns each slot's
    source entry (0 where none), whether it has one, and its run (the last run begun by it)."""
    slot = torch.arange(size, device=begins.device)
    run = torch.searchsorted(begins, slot, right=True) - 1
    offset = slot - begins.index_select(0, run)
    valid = offset < lengths.index_select(0, run)
    source = torch.where(valid, starts.index_select(0, run) + offset, 0)
    return source, valid, run


@dataclass(frozen=True)
class _Segments:
    """Consecutive segments of slots: segment k starts at bases[k] (a (k, 1) device tensor) and
    all end at `size`."""

    bases: torch.Tensor
    size: int


def _segments(
    counts: torch.Tensor, starts: torch.Tensor, segments: _Segments
) -> tuple[torch.Tensor, ...]:
    """Runs of (segment k, batch sample b): `counts[k, b]` entries from `starts[k, b]`, each
    segment's samples one after the other from its base. Returns `_runs` of them, and each
    run's first slot (k, B)."""
    begins = _exclusive_cumsum(counts) + segments.bases
    source, valid, run = _runs(starts.flatten(), counts.flatten(), begins.flatten(), segments.size)
    return source, valid, run, begins


@dataclass(frozen=True)
class _Layout:
    """A capacity's layout: its host sizes and device constants (see the module docstring)."""

    nodes: _Segments  # L + 1 segments, each with its sink last
    sizes: list[int]  # the plan's: nodes of level >= l, l = 0..L (segments 0..L - l)
    sinks: torch.Tensor  # (L,) the sink of node segments 0..L-1 (levels L..1)
    edges: list[_Segments]  # per edge type, L segments (destination levels L..1)
    edge_ends: list[dict[int, int]]  # per edge type: the plan's sizes[l] -> its edges into them
    targets: _Segments  # one segment of capacity.targets slots
    outputs: torch.Tensor  # (capacity.targets,) the targets' slots
    rows: torch.Tensor  # (sizes[1] + 1,) 0..sizes[1]: the CSR rows of any layer

    @staticmethod
    def of(capacity: Capacity, edge_types: int, device: torch.device) -> _Layout:
        layers = capacity.layers
        on = lambda values: torch.tensor(values, dtype=torch.int64, device=device)  # noqa: E731
        offsets = np.cumsum([0] + [size + 1 for size in capacity.nodes])  # a sink each
        sizes = [int(offsets[layers + 1 - level]) for level in range(layers + 1)]
        edges_, ends = [], []
        for index in range(edge_types):
            edge_offsets = np.cumsum([0, *capacity.edges(index)])
            edges_.append(_Segments(on(edge_offsets[:-1])[:, None], int(edge_offsets[-1])))
            ends.append(
                {
                    sizes[level]: int(edge_offsets[layers + 1 - level])
                    for level in range(1, layers + 1)
                }
            )
        return _Layout(
            nodes=_Segments(on(offsets[:-1])[:, None], int(offsets[-1])),
            sizes=sizes,
            sinks=on(offsets[1 : layers + 1] - 1),
            edges=edges_,
            edge_ends=ends,
            targets=_Segments(on([0])[:, None], capacity.targets),
            outputs=torch.arange(capacity.targets, device=device),
            rows=torch.arange(sizes[1] + 1, device=device),
        )


@dataclass(frozen=True)
class _EdgeTable:
    """One edge type's kept edges; split-global node ids."""

    src: torch.Tensor  # (E,) int32 (int64 past 2^31 nodes)
    dst: torch.Tensor  # (E,) int32 (int64 past 2^31 nodes)
    attr: torch.Tensor  # (E, 1) float32, scaled as Collate scales it
    start: torch.Tensor  # (S + 1, L) first edge of each sample's segment (row S: nothing)


@dataclass(frozen=True)
class TargetRows:
    """Per target of a split (T rows), as `aigem.batch.Batch` holds them: `xy` (T, K, 2) float32
    metres, `mask` (T, K) bool, `state` (T, 4) float32 physical, `cv_step` (T, 2) float32
    scaled."""

    xy: torch.Tensor
    mask: torch.Tensor
    state: torch.Tensor
    cv_step: torch.Tensor

    @staticmethod
    def of(batch: Batch) -> TargetRows:
        return TargetRows(batch.target_xy, batch.target_mask, batch.target_state, batch.cv_step)

    def map(self, each: Callable[[torch.Tensor], torch.Tensor]) -> TargetRows:
        """`each` of every field."""
        return TargetRows(*(each(getattr(self, f.name)) for f in fields(self)))


@dataclass(frozen=True)
class ResidentSplit:
    """The kept nodes, edges and targets of a split's S samples on one device; sample s is the
    split's sample s. `counts` (S, Q) on the host: each sample's entries per segment (the
    quantities of aigem.capacity), what capacities and batch sizes are chosen from."""

    layers: int
    counts: np.ndarray  # (S, Q) int64, host
    device_counts: torch.Tensor  # (S + 1, Q) on the device, row S zeros: a padded batch's id
    x: torch.Tensor  # (N, 4) float32 scaled features
    node_segment: torch.Tensor  # (N,) int8 L - level
    node_within: torch.Tensor  # (N,) int32 position among its sample's nodes of its segment
    node_start: torch.Tensor  # (S + 1, L + 1) first node of each sample's segment
    edges: tuple[_EdgeTable, ...]  # per edge type
    target_start: torch.Tensor  # (S + 1,) first target of each sample
    targets: TargetRows
    layouts: dict[Capacity, _Layout] = field(default_factory=dict, compare=False, repr=False)

    @property
    def samples(self) -> int:
        return len(self.counts)

    @property
    def empty_id(self) -> int:
        """The id that pads a batch's sample ids: a sample of no nodes, edges or targets."""
        return self.samples

    def to(self, device: torch.device) -> ResidentSplit:
        """The split on `device`."""
        move = lambda t: t.to(device)  # noqa: E731
        return ResidentSplit(
            layers=self.layers,
            counts=self.counts,
            device_counts=move(self.device_counts),
            x=move(self.x),
            node_segment=move(self.node_segment),
            node_within=move(self.node_within),
            node_start=move(self.node_start),
            edges=tuple(
                _EdgeTable(move(t.src), move(t.dst), move(t.attr), move(t.start))
                for t in self.edges
            ),
            target_start=move(self.target_start),
            targets=self.targets.map(move),
        )

    def nbytes(self) -> int:
        targets = [getattr(self.targets, f.name) for f in fields(self.targets)]
        tensors = [self.x, self.node_segment, self.node_within, *targets]
        tensors += [t for e in self.edges for t in (e.src, e.dst, e.attr)]
        return sum(t.numel() * t.element_size() for t in tensors)

    def batch(self, ids: torch.Tensor, capacity: Capacity) -> Batch:
        """The static batch of samples `ids` ((capacity.samples,) on the device, padded with
        `empty_id`) in `capacity`'s layout: its nodes in plan order, its edges in its plan's
        adjacency (`Batch.edges` empty), its targets the first nodes; a padded target's
        `target_sample` is -1, its values zeros."""
        layout = self._layout(capacity, ids.device)
        layers, count = self.layers, self.device_counts.index_select(0, ids)  # (B, Q)
        node, valid, _, begins = _segments(
            count[:, : layers + 1].t(), self.node_start.index_select(0, ids).t(), layout.nodes
        )
        x = self.x.index_select(0, node) * valid[:, None]
        adjacency = [
            self._edges(index, ids, count, capacity, layout, begins)
            for index in range(len(self.edges))
        ]
        target, valid, run, _ = _segments(
            count[:, :1].t(), self.target_start.index_select(0, ids)[None], layout.targets
        )

        def picked(values: torch.Tensor) -> torch.Tensor:
            values = values.index_select(0, target)
            mask = valid.view(-1, *[1] * (values.dim() - 1))
            return values & mask if values.dtype == torch.bool else values * mask

        rows = self.targets.map(picked)
        return Batch(
            x=x,
            target_node=layout.outputs,
            target_sample=torch.where(valid, run, -1),  # run: the target's sample in the batch
            target_xy=rows.xy,
            target_mask=rows.mask,
            target_state=rows.state,
            cv_step=rows.cv_step,
            plan=Plan(None, layout.sizes, adjacency, layout.outputs),
            graphs=capacity.samples,
        )

    def _layout(self, capacity: Capacity, device: torch.device) -> _Layout:
        """The layout of a capacity, made once (its device tensors made outside any capture)."""
        if capacity not in self.layouts:
            self.layouts[capacity] = _Layout.of(capacity, len(self.edges), device)
        return self.layouts[capacity]

    def _edges(self, index, ids, count, capacity, layout, node_begins) -> Adjacency:  # noqa: ANN001
        """Edge type `index` of the batch: its segments, their sources and destinations as node
        slots, padded from sink to sink; `node_begins` (L + 1, B) each node run's first slot."""
        samples, table = capacity.samples, self.edges[index]
        edge, valid, run, _ = _segments(
            count[:, edge_columns(self.layers, index)].t(),
            table.start.index_select(0, ids).t(),
            layout.edges[index],
        )
        member, node_begins = run % samples, node_begins.flatten()  # each slot's batch sample

        def slot(nodes: torch.Tensor) -> torch.Tensor:
            segment = self.node_segment.index_select(0, nodes).long()
            within = self.node_within.index_select(0, nodes)
            return node_begins.index_select(0, segment * samples + member) + within

        sink = layout.sinks.index_select(0, run // samples)
        src = torch.where(valid, slot(table.src.index_select(0, edge)), sink)
        dst = torch.where(valid, slot(table.dst.index_select(0, edge)), sink)
        attr = table.attr.index_select(0, edge) * valid[:, None]
        crow = torch.searchsorted(dst, layout.rows)  # dst ascending: a CSR order
        return Adjacency(crow, src, dst, attr, layout.edge_ends[index])


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
    within = torch.arange(len(order)) - _exclusive_cumsum(node_counts).index_select(0, group)
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


def fits(nbytes: int, device: torch.device) -> tuple[bool, float]:
    """Whether splits of `nbytes` may go onto `device` (at most DEVICE_SHARE of a GPU's free
    memory; anything on the CPU), and its free bytes (inf on the CPU)."""
    if device.type != "cuda":
        return True, float("inf")
    gc.collect()  # an earlier fit's captured steps and splits, unreferenced, go back
    torch.cuda.empty_cache()  # and the allocator's cache with them: what is free is free
    free = torch.cuda.mem_get_info(device)[0]
    return nbytes <= DEVICE_SHARE * free, free


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
    `check_scaler`: refuse inputs outside the scaler's range (aigem.data.check_covered: a
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
        _EdgeTable(
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
