"""A worker's tasks: an input file's rows staged per recording and part of its vehicles."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from conftest import set_budget

from ngsim_graphs import layout
from ngsim_graphs import schema as s
from ngsim_graphs.config import BuildConfig
from ngsim_graphs.engine import staging, tasks
from ngsim_graphs.sources.contract import FileRows, Source
from ngsim_graphs.sources.limits import PhysicalLimits

KEY = ("us-101", "0750am-0805am")
LIMITS = PhysicalLimits(max_frame_id=1_000)  # the fake source's: what its reader is given
OTHER = ("us-101", "0805am-0820am")


def source_of(vehicle_ids: list[int | None], recording: list[int | None]) -> Source:
    """A source whose one file holds rows of the given vehicles, of recordings 0 (KEY) and 1."""
    rows = pl.DataFrame(
        {s.VEHICLE_ID: vehicle_ids, s.RECORDING_INDEX: recording},
        schema={s.VEHICLE_ID: pl.Int32, s.RECORDING_INDEX: pl.Int32},
    )
    read = FileRows(rows.lazy(), {KEY: 0, OTHER: 1}, report=None)  # the report is passed on as is
    return Source("fake", lambda paths: (paths, []), lambda *_: read, None, None, 0.1, LIMITS)


def staged_ids(staged: dict[int, Path]) -> dict[int, list[int]]:
    return {part: pl.read_ipc(path)[s.VEHICLE_ID].to_list() for part, path in staged.items()}


def test_rows_are_staged_by_recording_and_part_of_their_vehicle_ids(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Parts of 4 ids: 3 -> 0, 4 and 7 -> 1, 9 -> 2; the other recording has no rows, and is
    staged all the same (one empty part), to be built with no sample."""
    set_budget(monkeypatch, vehicles_per_part=4)
    source = source_of([7, 3, 9, 4, 3], [0, 0, 0, 0, 0])
    _, staged = tasks.read_file(source, Path("f.txt"), BuildConfig(), 5, tmp_path, False)
    assert staged_ids(staged[KEY]) == {0: [3, 3], 1: [7, 4], 2: [9]}
    assert staged[KEY][1] == staging.staged_raw_path(tmp_path, *KEY, 1, 5)
    assert staged_ids(staged[OTHER]) == {0: []}


def test_a_part_holds_only_its_own_recording_rows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Both recordings have vehicle 3 in part 0: each part file holds its recording's rows only,
    and rows of no recording (null index) are staged nowhere."""
    set_budget(monkeypatch, vehicles_per_part=4)
    source = source_of([3, 3, 9, 2, 5], [0, 1, 0, None, 1])
    _, staged = tasks.read_file(source, Path("f.txt"), BuildConfig(), 0, tmp_path, False)
    assert staged_ids(staged[KEY]) == {0: [3], 2: [9]}
    assert staged_ids(staged[OTHER]) == {0: [3], 1: [5]}


@pytest.mark.parametrize("batch_rows", [1, 3])
def test_rows_staged_a_batch_at_a_time_are_staged_in_the_order_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, batch_rows: int
) -> None:
    """Batches of 1 and 3 rows: each part's file holds its rows of every batch, in the order
    they were read, as one batch of all of them stages them (and nothing else is left)."""
    set_budget(monkeypatch, vehicles_per_part=4)
    ids, recording = [7, 3, 9, 4, 3, 5, 7, 1], [0, 0, 1, 0, None, 1, 0, 0]
    _, whole = tasks.read_file(
        source_of(ids, recording), Path("f.txt"), BuildConfig(), 1, tmp_path / "a", False
    )
    set_budget(monkeypatch, batch_rows=batch_rows)
    _, batched = tasks.read_file(
        source_of(ids, recording), Path("f.txt"), BuildConfig(), 1, tmp_path / "b", False
    )
    assert staged_ids(whole[KEY]) == {0: [3, 1], 1: [7, 4, 7]}
    assert staged_ids(whole[OTHER]) == {1: [5], 2: [9]}
    assert {k: staged_ids(v) for k, v in batched.items()} == {
        k: staged_ids(v) for k, v in whole.items()
    }
    staging = tmp_path / "b" / layout.STAGING_DIR
    assert sorted(p.name for p in staging.iterdir()) == [
        layout.recording_name(*k) for k in (KEY, OTHER)
    ]


def test_a_source_scratch_folder_is_removed_after_staging_and_after_an_error(
    tmp_path: Path,
) -> None:
    """The source is given a folder of its own per file, which is gone once the task ends."""
    seen = []

    def read_file(path, config, limits, file_index, strict, scratch):
        assert limits is LIMITS  # the source's own, passed on by the task
        seen.append(scratch)
        scratch.mkdir(parents=True)
        (scratch / "parsed.parquet").write_bytes(b"x")
        if file_index == 1:
            raise ValueError("a bad file")
        return FileRows(pl.LazyFrame({s.VEHICLE_ID: [3], s.RECORDING_INDEX: [0]}), {KEY: 0}, None)

    source = Source("fake", lambda paths: (paths, []), read_file, None, None, 0.1, LIMITS)
    tasks.read_file(source, Path("f.txt"), BuildConfig(), 0, tmp_path, False)
    with pytest.raises(ValueError, match="a bad file"):
        tasks.read_file(source, Path("g.txt"), BuildConfig(), 1, tmp_path, False)
    assert seen == [staging.staged_scratch_dir(tmp_path, i) for i in (0, 1)]
    assert not any(path.exists() for path in seen)


def test_a_row_without_a_vehicle_id_is_an_error_not_a_row_lost(tmp_path: Path) -> None:
    source = source_of([7, None], [0, 0])
    with pytest.raises(ValueError, match="without a vehicle id"):
        tasks.read_file(source, Path("f.txt"), BuildConfig(), 0, tmp_path, False)


@pytest.mark.parametrize(
    ("most_rows", "groups"),
    [
        (6, [[3, 4], [7, 9]]),  # rows before each vehicle: 0, 5, 7, 11 -> groups 0, 0, 1, 1
        (4, [[3], [4, 7], [9]]),  # 0, 5, 7, 11 -> 0, 1, 1, 2: vehicle 3 alone, over the limit
        (1_000, [[3, 4, 7, 9]]),
        (1, [[3], [4], [7], [9]]),
    ],
)
def test_a_part_is_cleaned_in_groups_of_whole_vehicles(most_rows: int, groups: list) -> None:
    """Vehicles 3, 4, 7 and 9 with 5, 2, 4 and 1 rows, in any order: consecutive ids, each
    group starting at the vehicle whose rows before it pass a multiple of `most_rows`."""
    ids = [7, 3, 4, 3, 9, 3, 7, 3, 4, 7, 3, 7]
    raw = pl.DataFrame({s.VEHICLE_ID: ids}, schema={s.VEHICLE_ID: pl.Int32}).lazy()
    chosen = [raw.filter(group).collect() for group in tasks.vehicle_groups(raw, most_rows)]
    assert [sorted(set(rows[s.VEHICLE_ID])) for rows in chosen] == groups
    assert sum(rows.height for rows in chosen) == len(ids)


def test_a_part_without_rows_is_one_group() -> None:
    raw = pl.DataFrame(schema={s.VEHICLE_ID: pl.Int32}).lazy()
    assert [raw.filter(g).collect().height for g in tasks.vehicle_groups(raw, 10)] == [0]
