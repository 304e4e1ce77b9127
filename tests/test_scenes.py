"""ngsim_graphs.scenes: what a panel draws is counted from the sample, on a hand-made batch whose
counts are known by hand and on a real tiny build checked against its samples table; the road
seen from above (travel to the right, the left of travel up, no axis inverted), a graph in equal
metres with its d_sense circle, a followed target's lines in its models' colours."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from PIL import Image

from ngsim_graphs import palette
from ngsim_graphs.build import open_build
from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.graphs import EdgeSet, GraphBatch
from ngsim_graphs.scene_graph import GRAPH_BOX_ASPECT
from ngsim_graphs.scene_graph import MARGIN_M as GRAPH_MARGIN_M
from ngsim_graphs.scene_target import MARGIN_M, MIN_LATERAL_SPAN_M
from ngsim_graphs.scenes import (
    DrawnScene,
    draw_scene,
    one_per_ego,
    scene_figure,
    scene_titles,
    vehicle_ids,
    write_scenes,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
D_SENSE_M = 12.0


def hand_batch() -> GraphBatch:
    """Two samples of 3 history steps (step 2 is the present).

    Sample 0: the ego (track 10) at steps 0-2; actor A (11) at 0-2; actor B (12) at 1-2.
    Nodes 0: ego@0, 1: A@0, 2: ego@1, 3: A@1, 4: B@1, 5: ego@2, 6: A@2, 7: B@2.
    Spatial: ego<->A at 0 (2 directed); ego<->A, ego<->B at 1 (4); at the present step 2:
    ego<->A, ego<->B (4 ego edges) and A<->B (2 actor edges). Temporal: 0->2, 2->5, 1->3, 3->6,
    4->7 (5). Targets: A@2, B@2.
    Sample 1: the ego (20) at 0-2, actor C (21) at step 2 only. Nodes 8: ego@0, 9: ego@1,
    10: ego@2, 11: C@2. Spatial at the present: ego<->C (2). Temporal: 8->9, 9->10 (2).
    Target: C, recorded at its first two future steps only.
    """
    xy = [(0, -6), (3, -2), (0, -3), (3, 1), (-3, 4), (0, 0), (3, 4), (-3, 7)]
    xy += [(0, -4), (0, -2), (0, 0), (3.5, 2)]
    features = np.array([(x, y, 0.0, 15.0) for x, y in xy], dtype=np.float64)
    spatial = [(0, 1), (1, 0), (2, 3), (3, 2), (2, 4), (4, 2)]
    spatial += [(5, 6), (5, 7), (6, 5), (7, 5), (6, 7), (7, 6)]
    spatial += [(10, 11), (11, 10)]
    temporal = [(0, 2), (2, 5), (1, 3), (3, 6), (4, 7), (8, 9), (9, 10)]
    target_xy = np.zeros((3, 4, 2))
    target_xy[:, :, 1] = np.arange(1, 5) * 3.0
    target_xy[:, :, 0] = [[3.0], [-3.0], [3.5]]
    mask = np.ones((3, 4), dtype=bool)
    mask[2, 2:] = False
    return GraphBatch(
        node_ptr=np.array([0, 8, 12]),
        node_sample=np.array([0] * 8 + [1] * 4),
        node_step=np.array([0, 0, 1, 1, 1, 2, 2, 2, 0, 1, 2, 2], dtype=np.int8),
        node_track=np.array([10, 11, 10, 11, 12, 10, 11, 12, 20, 20, 20, 21], dtype=np.int32),
        node_is_ego=np.array([1, 0, 1, 0, 0, 1, 0, 0, 1, 1, 1, 0], dtype=bool),
        node_features=features,
        edges={
            "spatial": EdgeSet(np.array(spatial, dtype=np.int64).T, np.ones(len(spatial))),
            "temporal": EdgeSet(np.array(temporal, dtype=np.int64).T, np.full(len(temporal), 0.2)),
        },
        target_node=np.array([6, 7, 11]),
        target_xy=target_xy,
        target_mask=mask,
        time_step_s=0.2,
    )


def _axes():  # noqa: ANN202
    return Figure().add_subplot()


def test_hand_made_counts() -> None:
    batch = hand_batch()
    assert draw_scene(_axes(), batch, 0, D_SENSE_M, "zero") == DrawnScene(
        nodes=8,
        spatial_edges=6,
        ego_edges=4,
        actor_edges=2,
        temporal_edges=5,
        targets=2,
        predicted={},
    )
    assert draw_scene(_axes(), batch, 1, D_SENSE_M, "one") == DrawnScene(
        nodes=4,
        spatial_edges=2,
        ego_edges=2,
        actor_edges=0,
        temporal_edges=2,
        targets=1,
        predicted={},
    )


def test_undirected_pairs_are_drawn_once() -> None:
    axes = _axes()
    draw_scene(axes, hand_batch(), 0, D_SENSE_M, "zero")
    lines = [c for c in axes.collections if isinstance(c, LineCollection)]
    # ego-actor pairs at the present (ego-A, ego-B), actor-actor (A-B), temporal edges
    assert [len(c.get_segments()) for c in lines] == [2, 1, 5]
    # plotted along the road, then to the left of travel: (y, -x)
    assert {tuple(map(tuple, s)) for s in lines[1].get_segments()} == {((4, -3), (7, 3))}


def test_a_graph_is_drawn_in_equal_metres_with_its_circle_travel_to_the_right() -> None:
    """Sample 0's drawn things span y -6..12 (the ego's oldest node, B's last future step) and
    x -3..3 (B and A): with a 5 m margin 28 m along and 16 m across, widened along to the
    panel's shape (16 / 0.3 m); the x axis grows with travel, the y axis upwards (the left of
    travel)."""
    axes = _axes()
    draw_scene(axes, hand_batch(), 0, D_SENSE_M, "zero")
    (circle,) = [p for p in axes.patches if isinstance(p, Circle)]
    assert circle.get_radius() == D_SENSE_M and circle.center == (0.0, 0.0)
    assert axes.get_aspect() == 1.0 and axes.get_box_aspect() == GRAPH_BOX_ASPECT
    assert not axes.xaxis_inverted() and not axes.yaxis_inverted()
    along = 16 / GRAPH_BOX_ASPECT
    assert axes.get_xlim() == pytest.approx((3 - along / 2, 3 + along / 2))
    assert axes.get_ylim() == (-3 - GRAPH_MARGIN_M, 3 + GRAPH_MARGIN_M)
    assert "equal metres" in axes.get_ylabel() and "travel to the right" in axes.get_xlabel()


def test_a_followed_target_its_truth_and_predictions_in_their_colours() -> None:
    """Sample 1's target C (target 2): its history (one node, at (3.5, 2)), its truth (two
    recorded steps), each prediction a line from its present position, and a dot at each whole
    second; no edge, no circle, no other target."""
    axes = _axes()
    batch = hand_batch()
    predictions = {"AiGem": np.zeros((3, 4, 2)), "constant velocity": np.ones((3, 4, 2))}
    scene = draw_scene(axes, batch, 1, D_SENSE_M, "recording, ego 20", predictions, follow=2)
    assert scene.predicted == {"AiGem": 1, "constant velocity": 1}
    assert scene == DrawnScene(4, 2, 2, 0, 2, 1, scene.predicted)  # counted as a graph's
    history, truth, truth_dots, aigem, aigem_dots, cv, cv_dots = axes.lines
    assert history.get_xydata().tolist() == [[2.0, -3.5]]
    assert np.array_equal(truth.get_xydata()[:, 0], [2, 3, 6, np.nan, np.nan], equal_nan=True)
    assert aigem.get_xydata().tolist() == [[2.0, -3.5], *[[0.0, 0.0]] * 4]
    assert cv.get_xydata().tolist() == [[2.0, -3.5], *[[1.0, -1.0]] * 4]
    colours = [to_hex(line.get_color()) for line in (truth, aigem, cv)]
    assert colours == [to_hex(c) for c in (palette.TRUTH, palette.AIGEM, palette.CONSTANT_VELOCITY)]
    assert len(truth_dots.get_xydata()) == 0  # 4 steps of 0.2 s: no whole second
    assert not [p for p in axes.patches if isinstance(p, Circle)]
    assert len([c for c in axes.collections if isinstance(c, LineCollection)]) == 1  # context
    assert axes.get_title() == "recording, ego 20"
    # Along: from the history (y 2) and the ego (0) to the truth's y 6; across: the ego (0) to
    # the target (-3.5), widened to 12 m; the stretch said on the label.
    assert axes.get_xlim() == (0 - MARGIN_M, 6 + MARGIN_M)
    assert axes.get_ylim() == (-1.75 - MIN_LATERAL_SPAN_M / 2, -1.75 + MIN_LATERAL_SPAN_M / 2)
    assert axes.get_ylabel().endswith(f"stretched ×{0.45 * 16 / 12:.1f}")


def test_predictions_need_a_followed_target() -> None:
    with pytest.raises(ValueError, match="give `follow`"):
        draw_scene(_axes(), hand_batch(), 1, D_SENSE_M, "t", {"AiGem": np.zeros((3, 4, 2))})
    with pytest.raises(ValueError, match="target 0 is not one of the sample's \\[2\\]"):
        draw_scene(_axes(), hand_batch(), 1, D_SENSE_M, "t", follow=0)


def _enclosed(axes: Axes, plotted: np.ndarray) -> bool:
    (left, right), (bottom, top) = axes.get_xlim(), sorted(axes.get_ylim())
    finite = plotted[np.isfinite(plotted).all(axis=1)]
    return bool(
        (finite[:, 0] > left).all()
        and (finite[:, 0] < right).all()
        and (finite[:, 1] > bottom).all()
        and (finite[:, 1] < top).all()
    )


def _as_plotted(xy: np.ndarray) -> np.ndarray:
    return np.stack([xy[:, 1], -xy[:, 0]], axis=1)


def test_each_graph_panel_holds_its_data_in_equal_metres(tiny_build: Path) -> None:
    """On a real build and a 50 m d_sense: each panel's axes enclose its nodes and truth, along
    the road horizontally, in equal metres (the box's shape is the limits' ratio)."""
    opened = open_build(tiny_build)
    ids = np.arange(3)
    batch = opened.graphs("val", ids)
    figure, _ = scene_figure(batch, ["a", "b", "c"], 50.0)
    for b, axes in enumerate(figure.axes):
        nodes = batch.node_features[batch.node_ptr[b] : batch.node_ptr[b + 1], :2]
        targets = batch.node_sample[batch.target_node] == b
        truth = np.where(batch.target_mask[targets][..., None], batch.target_xy[targets], np.nan)
        for xy in (nodes, truth.reshape(-1, 2)):
            assert _enclosed(axes, _as_plotted(xy)), b
        along, across = np.ptp(axes.get_xlim()), np.ptp(axes.get_ylim())
        assert across == pytest.approx(GRAPH_BOX_ASPECT * along) and axes.get_aspect() == 1.0


def test_the_legend_tells_truth_predictions_history_and_neighbours_apart() -> None:
    predictions = {"AiGem": np.zeros((3, 4, 2)), "constant velocity": np.ones((3, 4, 2))}
    figure, _ = scene_figure(hand_batch(), ["a", "b"], D_SENSE_M, predictions, follow=[0, 2])
    (legend,) = figure.legends
    handles = {
        text.get_text(): line
        for text, line in zip(legend.texts, legend.legend_handles, strict=True)
    }
    for label in (
        "truth: its recorded future",
        "predicted: AiGem",
        "predicted: constant velocity",
        "followed target's history",
        "other vehicles (faded)",
    ):
        assert label in handles
    lines = [handles[name] for name in handles if name.startswith(("truth", "predicted"))]
    assert len({line.get_color() for line in lines}) == 3
    assert len({(line.get_linestyle(), str(line._dash_pattern)) for line in lines}) == 3
    assert len({line.get_marker() for line in lines}) == 3  # None for truth, X and ^
    # the panels draw them as the legend shows them
    drawn = {(line.get_color(), line.get_marker()) for line in figure.axes[0].lines}
    assert {(line.get_color(), line.get_marker()) for line in lines} <= drawn
    graph, _ = scene_figure(hand_batch(), ["a", "b"], D_SENSE_M)
    labels = [text.get_text() for text in graph.legends[0].texts]
    assert "d_sense around the ego" in labels and "spatial edge neighbours" in labels


def test_one_panel_per_ego() -> None:
    samples = pl.DataFrame(
        {
            "sample_id": [0, 1, 2, 3, 4, 5, 6],
            "location": ["us-101"] * 6 + ["i-80"],
            "period": ["a"] * 7,
            "ego_track_id": [7, 7, 8, 7, 9, 9, 7],
        }
    )
    assert one_per_ego(samples, 0, 8) == [0, 2, 4, 6]  # (i-80, 7) is another ego
    assert one_per_ego(samples, 0, 2) == [0, 2]
    assert one_per_ego(samples, 3, 2) == [3, 4]


@pytest.mark.parametrize("shape", [(2, 4, 2), (3, 5, 2), (3, 4, 3), (3, 4)])
def test_predictions_of_another_shape(shape: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="expected \\(3, K <= 4, 2\\)"):
        draw_scene(_axes(), hand_batch(), 0, D_SENSE_M, "t", {"bad": np.zeros(shape)})


def test_sample_out_of_the_batch() -> None:
    with pytest.raises(ValueError, match="sample 2 is not in a batch of 2"):
        draw_scene(_axes(), hand_batch(), 2, D_SENSE_M, "t")


def test_write_scenes_png(tmp_path: Path) -> None:
    path = tmp_path / "scenes.png"
    predictions = {"model": np.zeros((3, 4, 2))}
    scenes = write_scenes(
        path, hand_batch(), ["a", "b"], D_SENSE_M, predictions, columns=1, follow=[1, 2]
    )
    assert [s.nodes for s in scenes] == [8, 4] and [s.predicted for s in scenes] == [
        {"model": 1},
        {"model": 1},
    ]
    assert path.read_bytes().startswith(PNG_SIGNATURE) and path.stat().st_size > 20_000
    width, height = Image.open(path).size
    assert height > width  # one column of two panels
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenes.png"]  # no partial file left


def test_write_scenes_refuses_to_replace(tmp_path: Path) -> None:
    path = tmp_path / "taken.png"
    path.write_text("mine\n")
    with pytest.raises(NgsimOutputError, match="exists; not replaced"):
        write_scenes(path, hand_batch(), ["a", "b"], D_SENSE_M, overwrite=False)
    assert path.read_text() == "mine\n" and len(list(tmp_path.iterdir())) == 1
    write_scenes(path, hand_batch(), ["a", "b"], D_SENSE_M)  # overwrite, by default
    assert path.read_bytes().startswith(PNG_SIGNATURE)


def test_write_scenes_needs_a_title_per_sample(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="1 titles for 2 samples"):
        write_scenes(tmp_path / "x.png", hand_batch(), ["a"], D_SENSE_M)


def _present_spatial_edges(batch: GraphBatch, sample: int) -> tuple[int, int]:
    """(ego, actor-actor) directed spatial edges of a sample at its present step, edge by edge."""
    first, last = batch.node_ptr[sample], batch.node_ptr[sample + 1]
    present = max(batch.node_step[first:last])
    ego = actor = 0
    for source, destination in batch.edges["spatial"].index.T:
        if first <= source < last and batch.node_step[source] == present:
            if batch.node_is_ego[source] or batch.node_is_ego[destination]:
                ego += 1
            else:
                actor += 1
    return ego, actor


def test_counts_of_a_real_build(tiny_build: Path, tmp_path: Path) -> None:
    opened = open_build(tiny_build)
    ids = np.arange(4)
    batch = opened.graphs("val", ids)
    samples = opened.samples("val")
    titles = scene_titles(samples, "val", ids)
    scenes = write_scenes(tmp_path / "val.png", batch, titles, opened.config.d_sense_m)
    assert len(scenes) == 4
    for b, scene in enumerate(scenes):
        row = samples.row(b, named=True)
        assert scene.nodes == row["n_nodes"] == batch.node_ptr[b + 1] - batch.node_ptr[b]
        assert scene.temporal_edges == row["n_temporal_edges"]
        assert scene.targets == row["n_targets"]
        assert (scene.ego_edges, scene.actor_edges) == _present_spatial_edges(batch, b)
        assert scene.spatial_edges == scene.ego_edges + scene.actor_edges
        assert scene.spatial_edges <= row["n_spatial_edges"]
    assert sum(scene.spatial_edges for scene in scenes) > 0  # the check above checked something
    assert titles[0] == (
        f"{row['location']} {row['period']}, ego vehicle {samples['ego_vehicle_id'][0]}, val #0"
    )


def test_vehicle_ids_of_tracks(tiny_build: Path) -> None:
    tracks = open_build(tiny_build).tracks()
    rows = tracks.select("track_id", "vehicle_id").unique().sort("track_id").collect()
    first, last = rows.row(0), rows.row(-1)
    assert vehicle_ids(tracks, [first[0], last[0]]) == {first[0]: first[1], last[0]: last[1]}
