"""Graphs of chosen samples as explicit Parquet-ready tables with sample-local node indices.

The build stores graphs compactly (grid nodes and proximity pairs, once per step); these tables
are the per-sample form of the build's graphs (docs/build-format.md), for any subset a researcher
wants to look at or feed to another tool. They are written as a whole into a hidden folder
beside the target and renamed into place when complete, with EXPORT_MARKER listing them and
their sha256; a target that holds anything but the tables its marker lists, as they were
written, is never replaced.
"""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import numpy as np
import polars as pl

from ngsim_graphs import edges, landing, storage
from ngsim_graphs import schema as s
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.graphs import GraphBatch
from ngsim_graphs.integrity import file_sha256


def export_tables() -> tuple[str, ...]:
    """The tables an export may write: nodes, one per edge type (`<name>_edges`, of every type
    `edges.EDGE_TYPES` knows: an export writes those of its build's), targets, samples."""
    return ("nodes", *(edge.table for edge in edges.EDGE_TYPES.values()), "targets", "samples")


EXPORT_MARKER = "export.json"  # the tables an export wrote, with their sha256
EXPORT_PROGRAM = "ngsim-graphs export"


def graph_tables(batch: GraphBatch, sample_ids: np.ndarray) -> dict[str, pl.DataFrame]:
    """nodes, the edge tables (one per edge type) and targets of the samples of `batch`.

    `sample_ids[b]` is the split's sample id of the batch's sample b.
    """
    sample_of_node = np.asarray(sample_ids)[batch.node_sample]
    local = np.arange(len(batch.node_sample)) - batch.node_ptr[batch.node_sample]
    nodes = pl.DataFrame(
        {
            s.SAMPLE_ID: sample_of_node,
            s.NODE: local,
            s.K: batch.node_step,
            s.TRACK_ID: batch.node_track,
            s.IS_EGO: batch.node_is_ego,
            s.X_M: batch.node_features[:, 0],
            s.Y_M: batch.node_features[:, 1],
            s.HEADING_RAD: batch.node_features[:, 2],
            s.SPEED_MPS: batch.node_features[:, 3],
        }
    )

    def edge_table(pairs: np.ndarray) -> dict[str, np.ndarray]:
        return {
            s.SAMPLE_ID: sample_of_node[pairs[0]],
            s.K: batch.node_step[pairs[0]],
            s.EDGE_SOURCE: local[pairs[0]],
            s.EDGE_DESTINATION: local[pairs[1]],
        }

    n_targets, k_f = batch.target_mask.shape
    target = np.repeat(batch.target_node, k_f)
    targets = pl.DataFrame(
        {
            s.SAMPLE_ID: sample_of_node[target],
            s.NODE: local[target],
            s.TRACK_ID: batch.node_track[target],
            s.FUTURE_STEP: np.tile(np.arange(k_f), n_targets),
            s.X_M: batch.target_xy[..., 0].reshape(-1),
            s.Y_M: batch.target_xy[..., 1].reshape(-1),
            s.RECORDED: batch.target_mask.reshape(-1),
        }
    )
    order = [s.SAMPLE_ID, s.K, s.EDGE_SOURCE, s.EDGE_DESTINATION]
    edge_tables = {
        edge.table: pl.DataFrame(
            {
                **edge_table(batch.edges[edge.name].index),
                edge.attribute: batch.edges[edge.name].attribute,
            }
        ).sort(order)
        for edge in edges.types_of(tuple(batch.edges))
    }
    return {
        "nodes": nodes.sort(s.SAMPLE_ID, s.NODE),
        **edge_tables,
        "targets": targets.with_columns(
            pl.when(pl.col(s.RECORDED)).then(pl.col(s.X_M)).alias(s.X_M),
            pl.when(pl.col(s.RECORDED)).then(pl.col(s.Y_M)).alias(s.Y_M),
        ).sort(s.SAMPLE_ID, s.NODE, s.FUTURE_STEP),
    }


def earlier_export_files(out: Path) -> set[str] | None:
    """The files of an earlier export in `out` (its marker and the tables it lists that are
    there, each as it was written), or None where `out` holds no export's marker."""
    document = landing.json_object(out / EXPORT_MARKER)
    if document is None or document.get("program") != EXPORT_PROGRAM:
        return None
    tables = document.get("tables")
    ours = {f"{name}.parquet" for name in export_tables()}
    if not isinstance(tables, dict) or not set(tables) <= ours:
        return None
    present = {name for name in tables if (out / name).is_file()}
    if any(file_sha256(out / name) != tables[name] for name in present):
        return None  # a table replaced or edited since: not the export's any more
    return {EXPORT_MARKER, *present}


def check_export_target(out: Path, overwrite: bool) -> None:
    """Refuse a target folder that must not be replaced: a file, a folder holding anything but
    an earlier export's files as it wrote them, or (without `overwrite`) an earlier export. A new
    or empty folder is taken."""
    if out.exists() and not out.is_dir():
        raise NgsimOutputError(out, "exists and is not a directory")
    entries = sorted(out.iterdir()) if out.is_dir() else []
    ours = earlier_export_files(out) if entries else set()
    foreign = [p.name for p in entries if p.name not in (ours or ()) or p.is_symlink()]
    if foreign:
        raise NgsimOutputError(
            out,
            f"folder is not empty: it holds {landing.some_names(foreign)}, which export did not "
            "write; choose a new or empty folder",
        )
    if entries and not overwrite:
        raise NgsimOutputError(out, "holds an export already; pass --overwrite to replace it")


def write_tables(tables: dict[str, pl.DataFrame], out: Path, overwrite: bool) -> list[Path]:
    """Write `tables` as `out/<name>.parquet`, replacing `out` as a whole once all are written.

    Raises NgsimOutputError where `out` must not be replaced (see `check_export_target`) or a
    table cannot be written (a full disk); `out` is then left as it was.
    """
    unknown = sorted(set(tables) - set(export_tables()))
    if unknown:
        raise ValueError(f"not export tables: {', '.join(unknown)}")
    check = partial(check_export_target, overwrite=overwrite)
    with landing.output_directory(out, check) as folder:
        for name, table in tables.items():
            storage.write_parquet(table, folder / f"{name}.parquet")
        sums = {f"{name}.parquet": file_sha256(folder / f"{name}.parquet") for name in tables}
        document = {"program": EXPORT_PROGRAM, "tables": sums}
        (folder / EXPORT_MARKER).write_text(json.dumps(document, indent=2) + "\n")
    return [out / f"{name}.parquet" for name in tables]
