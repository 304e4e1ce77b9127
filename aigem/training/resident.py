"""A split on the device, and static batches assembled there by index (docs/aigem.md).

A `ResidentSplit` holds what the encoder reads of every graph of a split as flat tensors
(aigem.training.loading makes it): a sample's nodes ordered by level, the last layer that needs the node
(`aigem.model.plan.node_levels`: L at the targets), and only the edges into a node of level >= 1.

`ResidentSplit.batch(ids, capacity)` assembles the graphs of the samples `ids` on the device in
the layout of `aigem.training.capacity`: node segment k holds every sample's nodes of level L - k, in the
order of `ids`, padded to the capacity, then one spare node, the segment's sink; edge segment k of
a type holds its edges into segment k's nodes, by destination (a CSR order), padded with edges
from the sink to the sink. So layer l reads a prefix of the nodes and computes a shorter prefix,
from a prefix of each type's edges (an `aigem.model.plan.Plan` with no reordering), and the targets
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

from aigem.model.batch import Batch
from aigem.model.plan import Adjacency, Plan
from aigem.training.capacity import Capacity, edge_columns

DEVICE_SHARE = 0.5  # of a GPU's free memory the splits may take: the rest for the steps


def exclusive_cumsum(counts: torch.Tensor) -> torch.Tensor:
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
    begins = exclusive_cumsum(counts) + segments.bases
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
class EdgeTable:
    """One edge type's kept edges; split-global node ids."""

    src: torch.Tensor  # (E,) int32 (int64 past 2^31 nodes)
    dst: torch.Tensor  # (E,) int32 (int64 past 2^31 nodes)
    attr: torch.Tensor  # (E, 1) float32, scaled as Collate scales it
    start: torch.Tensor  # (S + 1, L) first edge of each sample's segment (row S: nothing)


@dataclass(frozen=True)
class TargetRows:
    """Per target of a split (T rows), as `aigem.model.batch.Batch` holds them: `xy` (T, K, 2) float32
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
    quantities of aigem.training.capacity), what capacities and batch sizes are chosen from."""

    layers: int
    counts: np.ndarray  # (S, Q) int64, host
    device_counts: torch.Tensor  # (S + 1, Q) on the device, row S zeros: a padded batch's id
    x: torch.Tensor  # (N, 4) float32 scaled features
    node_segment: torch.Tensor  # (N,) int8 L - level
    node_within: torch.Tensor  # (N,) int32 position among its sample's nodes of its segment
    node_start: torch.Tensor  # (S + 1, L + 1) first node of each sample's segment
    edges: tuple[EdgeTable, ...]  # per edge type
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
                EdgeTable(move(t.src), move(t.dst), move(t.attr), move(t.start)) for t in self.edges
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


def fits(nbytes: int, device: torch.device) -> tuple[bool, float]:
    """Whether splits of `nbytes` may go onto `device` (at most DEVICE_SHARE of a GPU's free
    memory; anything on the CPU), and its free bytes (inf on the CPU)."""
    if device.type != "cuda":
        return True, float("inf")
    gc.collect()  # an earlier fit's captured steps and splits, unreferenced, go back
    torch.cuda.empty_cache()  # and the allocator's cache with them: what is free is free
    free = torch.cuda.mem_get_info(device)[0]
    return nbytes <= DEVICE_SHARE * free, free
