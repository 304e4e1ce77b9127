"""Edited and damaged builds: one line naming the file, never silently wrong numbers.

Each case copies a finished build, damages one thing and runs what a user would run (`stats`,
`export`, `verify`, the dataset); the manifest records every file's size, checksum and array
shape, and its own checksum.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from test_cli_ngsim import error_line, invoke
from typer.testing import CliRunner, Result

from ngsim_graphs import integrity, layout
from ngsim_graphs.build import open_build, verify_build
from ngsim_graphs.errors import NgsimInputError


@pytest.fixture
def copy(tiny_build: Path, tmp_path: Path) -> Path:
    target = tmp_path / "build"
    shutil.copytree(tiny_build, target)
    return target


DIGEST_MISMATCH = (
    "its bytes do not match the manifest's digest: edited or damaged (build it again; "
    "`ngsim-graphs verify` names every damaged file)"
)


def manifest_of(build: Path) -> dict:
    return json.loads((build / layout.MANIFEST_NAME).read_text())


def rewrite(build: Path, manifest: dict, checksum: bool = False) -> None:
    """Write an edited manifest; with `checksum`, as a careful forger would (checksum redone)."""
    if checksum:
        manifest = integrity.with_checksum(manifest)
    (build / layout.MANIFEST_NAME).write_text(json.dumps(manifest))


def first_arrays(build: Path) -> Path:
    entry = manifest_of(build)["recordings"][0]
    return layout.recording_arrays_dir(build, entry["location"], entry["period"])


def test_the_manifest_records_every_file(tiny_build: Path) -> None:
    manifest = manifest_of(tiny_build)
    files = sorted(str(p.relative_to(tiny_build)) for p in tiny_build.rglob("*") if p.is_file())
    assert sorted(manifest["files"]) == [f for f in files if f != layout.MANIFEST_NAME]
    for relative, record in manifest["files"].items():
        data = (tiny_build / relative).read_bytes()
        assert record["bytes"] == len(data) and record["sha256"] == hashlib.sha256(data).hexdigest()
    node_state = manifest["files"][
        str((first_arrays(tiny_build) / "node_state.npy").relative_to(tiny_build))
    ]
    assert node_state["dtype"] == "<f8" and node_state["shape"][1] == 4
    body = {k: v for k, v in manifest.items() if k != "manifest_sha256"}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"))
    assert manifest["manifest_sha256"] == hashlib.sha256(canonical.encode()).hexdigest()
    result = invoke("verify", tiny_build)
    assert result.exit_code == 0 and f"all {len(manifest['files'])} files match" in result.stdout


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m["scaler"]["x_m"].update(max=m["scaler"]["x_m"]["max"] * 7),  # ADE 24 -> 175 m
        lambda m: m["splits"].update(train=10),  # fit would train on 10 graphs
        lambda m: m["config"].update(d_sense_m=1.0),  # evaluate would score 0 actors
    ],
    ids=["scaler", "split sizes", "config"],
)
def test_an_edited_manifest_is_refused(copy: Path, edit: Callable[[dict], None]) -> None:
    manifest = manifest_of(copy)
    edit(manifest)
    rewrite(copy, manifest)
    for command in (
        ("stats", copy),
        ("verify", copy),
        ("export", copy, "--out", copy.parent / "t"),
    ):
        line = error_line(invoke(*command))
        assert f"{copy / layout.MANIFEST_NAME}: its content does not match its checksum" in line


def test_an_edited_config_with_a_forged_checksum_still_fails_its_hash(copy: Path) -> None:
    manifest = manifest_of(copy)
    manifest["config"]["d_sense_m"] = 1.0
    rewrite(copy, manifest, checksum=True)
    line = error_line(invoke("stats", copy))
    assert "its config does not match its config_hash" in line


def test_forged_split_sizes_disagree_with_the_sample_arrays(copy: Path) -> None:
    manifest = manifest_of(copy)
    manifest["splits"]["train"] = 10
    rewrite(copy, manifest, checksum=True)
    with pytest.raises(
        NgsimInputError, match="samples-train: the arrays do not hold the 10 samples"
    ):
        open_build(copy).graphs("train", np.arange(3))


def test_a_truncated_array_names_its_file(copy: Path) -> None:
    path = first_arrays(copy) / "node_state.npy"
    path.write_bytes(path.read_bytes()[:-100])
    line = error_line(invoke("stats", copy))
    assert (
        f"{path}: " in line and "bytes where the manifest records" in line and "truncated" in line
    )


def test_a_reshaped_array_of_the_same_size_names_its_file(copy: Path) -> None:
    path = first_arrays(copy) / "node_state.npy"
    array = np.load(path)
    np.save(path, array.reshape(-1, 2))  # the header grows by no byte: same size, other shape
    assert path.stat().st_size == manifest_of(copy)["files"][str(path.relative_to(copy))]["bytes"]
    line = error_line(invoke("stats", copy))
    assert (
        f"{path}: <f8 ({array.shape[0] * 2}, 2) where the manifest records <f8 ({array.shape[0]}, 4)"
        in line
    )


def test_nan_in_the_node_array(copy: Path) -> None:
    opened = open_build(copy)  # before the edit: the values are the last line of defence
    path = first_arrays(copy) / "node_state.npy"
    array = np.load(path, mmap_mode="r+")
    array[:, 0] = np.nan  # the same size and shape: only the digests or the values tell
    array.flush()
    del array
    with pytest.raises(NgsimInputError, match="node_state.npy: holds values that are not finite"):
        opened.graphs("train", np.arange(4))
    line = error_line(invoke("stats", copy))
    assert line == f"error: {path}: {DIGEST_MISMATCH}"
    result = invoke("verify", copy)
    assert result.exit_code == 1
    assert (
        result.stderr.strip()
        == f"error: {path}: its bytes do not match the manifest's sha256 (damaged or edited)"
    )


def test_verify_names_every_damaged_file(copy: Path) -> None:
    records = manifest_of(copy)["files"]
    damaged = sorted(records)[:2]
    for relative in damaged:
        data = bytearray((copy / relative).read_bytes())
        data[-1] ^= 0xFF
        (copy / relative).write_bytes(bytes(data))
    problems = verify_build(copy).problems
    assert problems == tuple(
        f"{copy / r}: its bytes do not match the manifest's sha256 (damaged or edited)"
        for r in damaged
    )


def test_a_missing_file(copy: Path) -> None:
    (copy / "samples" / "val.parquet").unlink()
    line = error_line(invoke("stats", copy))
    assert f"{copy / 'samples' / 'val.parquet'}: missing: the build is incomplete" in line


@pytest.mark.parametrize("where", ["/etc/passwd", "../outside.npy", "arrays/../../outside.npy"])
def test_a_manifest_never_leads_reads_outside_its_build(copy: Path, where: str) -> None:
    (copy.parent / "outside.npy").write_bytes(b"")
    manifest = manifest_of(copy)
    manifest["files"][where] = {"bytes": 0, "sha256": hashlib.sha256(b"").hexdigest()}
    rewrite(copy, manifest, checksum=True)
    line = error_line(invoke("stats", copy))
    assert "names a file outside the build or of an odd name" in line and repr(where) in line


def test_a_recording_name_is_never_a_path(copy: Path) -> None:
    manifest = manifest_of(copy)
    manifest["recordings"][0]["location"] = "/tmp"  # arrays_dir is no longer read at all
    rewrite(copy, manifest, checksum=True)
    line = error_line(invoke("stats", copy))
    assert "names a file outside the build or of an odd name: '/tmp'" in line


@pytest.mark.parametrize("content", [b"[1, 2]", b"\xff\xfe{", b'{"format_version": 1}'])
def test_a_manifest_that_is_not_one(copy: Path, content: bytes) -> None:
    (copy / layout.MANIFEST_NAME).write_bytes(content)
    line = error_line(invoke("stats", copy))
    assert str(copy / layout.MANIFEST_NAME) in line
    assert any(
        f in line
        for f in (
            "not a JSON object",
            "not UTF-8",
            "format version 1; expected 4 or 3 (made by an older",
        )
    )


def test_an_array_header_claiming_more_than_the_file_holds(copy: Path) -> None:
    # The header edited in place (same size, so the size check passes): (N, 4) -> (10 N + 9, 4).
    path = first_arrays(copy) / "node_state.npy"
    data = path.read_bytes()
    rows = np.load(path, mmap_mode="r").shape[0]
    old, new = f"({rows}, 4)".encode(), f"({rows * 10 + 9}, 4)".encode()
    assert data.count(old) == 1
    header_end = data.index(b"\n") + 1
    # The header dict is padded with spaces up to its newline: take the growth from the padding.
    longer = data[:header_end].replace(old + b", }", new + b", }", 1)
    header = longer.replace(b" " * (len(new) - len(old)) + b"\n", b"\n")
    assert len(header) == header_end
    path.write_bytes(header + data[header_end:])
    assert path.stat().st_size == len(data)
    line = error_line(invoke("stats", copy))
    assert str(path) in line and (
        "unreadable array" in line or "where the manifest records" in line
    )


def shift_test_windows(build: Path) -> Path:
    """repro_6's first edit: every test window starts 5 steps later (the same bytes in all)."""
    path = build / "arrays" / "samples-test" / "start_step.npy"
    np.save(path, np.load(path) + 5)
    return path


def halve_pair_distances(build: Path) -> Path:
    """repro_6's second edit: a recording's pair distances halved (the same bytes in all)."""
    path = first_arrays(build) / "pair_dist.npy"
    np.save(path, np.load(path) * np.float32(0.5))
    return path


def aigem(*args: object) -> Result:
    from ngsim_cli.aigem import app  # torch loads only for the tests that use it

    return CliRunner(env={"COLUMNS": "200"}).invoke(app, [str(a) for a in args])


@pytest.mark.parametrize("edit", [shift_test_windows, halve_pair_distances])
def test_same_size_edits_are_refused_by_every_open(
    copy: Path, tiny_run: Path, edit: Callable[[Path], Path]
) -> None:
    records = manifest_of(copy)["files"]
    path = edit(copy)
    assert path.stat().st_size == records[path.relative_to(copy).as_posix()]["bytes"]
    expected = f"error: {path}: {DIGEST_MISMATCH}"
    out = copy.parent / "out"
    for result in (
        invoke("stats", copy),
        invoke("stats", copy, "--json"),
        invoke("export", copy, "--out", out),
        invoke("show", copy, "--out", out.with_suffix(".png")),
    ):
        assert error_line(result) == expected
    for result in (  # fit has told the model's size on stdout by then
        aigem("fit", copy, "--out", out, "--epochs", "1", "--device", "cpu"),
        aigem("evaluate", tiny_run, "--data", copy, "--device", "cpu"),
    ):
        assert (result.exit_code, result.stderr.strip()) == (1, expected)
    assert not out.exists() and not out.with_suffix(".png").exists()


def test_a_large_file_is_checked_by_samples(
    copy: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    block = integrity.SAMPLE_BLOCK_BYTES
    monkeypatch.setattr(integrity, "WHOLE_FILE_BYTES", 2 * block)
    monkeypatch.setattr(integrity, "SAMPLE_BLOCKS", 3)
    data = np.random.default_rng(0).bytes(100_000)
    big, small = tmp_path / "big", tmp_path / "small"
    big.write_bytes(data)
    small.write_bytes(data[: 2 * block])
    assert integrity.sample_offsets(100_000) == [0, 47_952, 95_904]  # (100,000 - 4,096) / 2
    picked = data[:block] + data[47_952 : 47_952 + block] + data[-block:]
    assert integrity.sampled_sha256(big) == hashlib.sha256(picked).hexdigest()
    assert integrity.sampled_sha256(small) == integrity.file_sha256(small)
    # Sealed with these sizes, a build's larger files are sampled; a spread edit is still found.
    body = {k: v for k, v in manifest_of(copy).items() if k not in ("files", "manifest_sha256")}
    layout.write_manifest_json(copy, body)
    assert invoke("stats", copy).exit_code == 0
    path = halve_pair_distances(copy)
    assert path.stat().st_size > 2 * block
    assert error_line(invoke("stats", copy)) == f"error: {path}: {DIGEST_MISMATCH}"


def test_verify_names_unlisted_files_and_every_link(copy: Path, tmp_path: Path) -> None:
    (copy / "arrays" / "notes.txt").write_text("mine\n")
    val = copy / "samples" / "val.parquet"
    outside = tmp_path / "val-elsewhere.parquet"
    shutil.copyfile(val, outside)
    val.unlink()
    val.symlink_to(outside)  # the same bytes, from elsewhere
    (copy / "again").symlink_to("arrays", target_is_directory=True)  # not followed
    result = invoke("verify", copy)
    assert result.exit_code == 1 and result.stdout == ""
    assert result.stderr.splitlines() == [
        f"error: {copy / 'again'}: a symbolic link to arrays, inside the build; a build holds "
        "only its own files (copy them in, or build it again)",
        f"error: {copy / 'arrays' / 'notes.txt'}: not listed in the manifest: not part of this "
        "build",
        f"error: {val}: a symbolic link to {outside}, outside the build; a build holds only its "
        "own files (copy them in, or build it again)",
    ]


def test_a_build_of_the_format_before_sampled_digests_is_refused(copy: Path) -> None:
    manifest = manifest_of(copy)
    for record in manifest["files"].values():
        del record["sampled_sha256"]
    rewrite(copy, {**manifest, "format_version": 2}, checksum=True)  # as version 2 sealed it
    assert error_line(invoke("stats", copy)) == (
        f"error: {copy / layout.MANIFEST_NAME}: format version 2; expected 4 or 3 (made by an older "
        "ngsim-graphs: build it again)"
    )


@pytest.mark.parametrize(
    "relative",
    ["samples/test.parquet", "samples/train.parquet", "tracks", "arrays/samples-val"],
)
def test_a_file_the_manifest_leaves_out_is_refused_by_every_open(copy: Path, relative: str) -> None:
    """A manifest re-sealed without a file's record: the file would be read unchecked (here an
    empty table in place of the test samples), so every open refuses it, naming it."""
    entry = manifest_of(copy)["recordings"][0]
    name = layout.recording_name(entry["location"], entry["period"])
    relative = {
        "tracks": f"tracks/{name}.parquet",
        "arrays/samples-val": "arrays/samples-val/start_step.npy",
    }.get(relative, relative)
    manifest = manifest_of(copy)
    del manifest["files"][relative]
    rewrite(copy, manifest, checksum=True)
    path = copy / relative
    if relative == "samples/test.parquet":
        pl.read_parquet(path).clear().write_parquet(path)  # what the record would have caught
    expected = f"error: {path}: {integrity.NOT_LISTED}"
    out = copy.parent / "out"
    for result in (
        invoke("stats", copy, "--json"),
        invoke("export", copy, "--out", out),
        invoke("show", copy, "--out", out.with_suffix(".png")),
    ):
        assert error_line(result) == expected
    fit = aigem("fit", copy, "--out", out, "--epochs", "1", "--device", "cpu")
    assert (fit.exit_code, fit.stderr) == (1, expected + "\n")
    assert not out.exists() and not out.with_suffix(".png").exists()
