"""The one rule for a folder of pictures (`stats --plots`, `evaluate --plots`): plots.json lists
the pictures that are ours to replace; anything else of their names stops the call before it
writes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.plot_folder import OWNED, claim_plot_folder, land_plots

STATS, EVALUATE = ("a.png", "b.png"), ("c.png",)


def _draw(folder: Path, names: tuple[str, ...], writer: str, data: bytes) -> list[Path]:
    owned = claim_plot_folder(folder, names, writer)
    return land_plots(folder, dict.fromkeys(names, data), owned, writer)


def test_two_commands_share_a_folder_and_replace_only_their_own(tmp_path: Path) -> None:
    folder = tmp_path / "plots"
    assert _draw(folder, STATS, "stats", b"1") == [folder / "a.png", folder / "b.png"]
    _draw(folder, EVALUATE, "evaluate", b"2")
    _draw(folder, STATS, "stats", b"3")  # its own pictures replaced; evaluate's stay listed
    assert {p.name: p.read_bytes() for p in folder.glob("*.png")} == {
        "a.png": b"3",
        "b.png": b"3",
        "c.png": b"2",
    }
    assert json.loads((folder / OWNED).read_text())["pictures"] == ["a.png", "b.png", "c.png"]
    owned = claim_plot_folder(folder, STATS, "stats")
    land_plots(folder, {"a.png": b"4"}, owned, "stats")  # b.png no longer drawn: removed
    assert sorted(p.name for p in folder.iterdir()) == ["a.png", "c.png", OWNED]


@pytest.mark.parametrize("kind", ["file", "link"])
def test_a_file_of_our_names_that_is_not_ours_is_refused(tmp_path: Path, kind: str) -> None:
    folder = tmp_path / "plots"
    folder.mkdir()
    if kind == "file":
        (folder / "b.png").write_bytes(b"mine")
    else:
        (folder / "b.png").symlink_to(tmp_path / "elsewhere.png")  # dangling: still the user's
    message = "exists and was not written by `stats`; move it or choose another --plots folder"
    with pytest.raises(NgsimOutputError, match=f"b.png: {message}$"):
        claim_plot_folder(folder, STATS, "stats")
    assert sorted(p.name for p in folder.iterdir()) == ["b.png"]


def test_a_plots_json_that_is_not_ours_is_refused(tmp_path: Path) -> None:
    (tmp_path / OWNED).write_text('{"my": "settings"}')
    with pytest.raises(NgsimOutputError, match="is not the list of plots of ngsim-graphs or aigem"):
        claim_plot_folder(tmp_path, STATS, "stats")
    (tmp_path / "taken").write_text("")
    with pytest.raises(NgsimOutputError, match="taken: cannot write plots: "):
        claim_plot_folder(tmp_path / "taken", STATS, "stats")
