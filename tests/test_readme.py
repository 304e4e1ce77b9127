"""The README's Python quick start, run as written against a tiny build and run laid out as the
README's commands leave them (demo/build, demo/run)."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

from aigem.config import ModelConfig, TrainConfig
from aigem.training import fit

README = Path(__file__).resolve().parents[1] / "README.md"


def quick_start_blocks() -> list[str]:
    """The Python code blocks of the README's "Python quick start" section, in order."""
    section = README.read_text().split("## Python quick start", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^```python\n(.*?)^```", section, flags=re.MULTILINE | re.DOTALL)


def test_the_quick_start_has_the_promised_parts() -> None:
    code = "\n".join(quick_start_blocks())
    for part in ("open_build(", "DataLoader(", "loss.backward()", "predict_samples(", "PygLoader("):
        assert part in code


@pytest.fixture(scope="module")
def demo(tiny_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder laid out as the README's commands leave it: demo/build, demo/run."""
    root = tmp_path_factory.mktemp("readme")
    (root / "demo").mkdir()
    (root / "demo" / "build").symlink_to(tiny_build, target_is_directory=True)
    config = TrainConfig(epochs=1, batch_size=8)
    fit(root / "demo" / "build", root / "demo" / "run", ModelConfig(), config, "cpu")
    return root


def run_blocks(blocks: list[str]) -> tuple[dict[str, object], str]:
    """Run the blocks one after the other in one fresh scope; (the scope, what they printed)."""
    scope: dict[str, object] = {"__name__": "readme"}
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        for block in blocks:
            exec(compile(block, str(README), "exec"), scope)  # noqa: S102 (our own README)
    return scope, printed.getvalue()


@pytest.mark.parametrize("index", range(len(quick_start_blocks())))
def test_each_block_runs_alone(demo: Path, monkeypatch: pytest.MonkeyPatch, index: int) -> None:
    """A reader copies one block: it must not lean on names another block defined."""
    monkeypatch.chdir(demo)
    _, out = run_blocks([quick_start_blocks()[index]])
    assert "torch.Size([" in out


def test_the_quick_start_runs_as_written(demo: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(demo)
    scope, out = run_blocks(quick_start_blocks())
    assert "torch.Size([" in out
    loss = scope["loss"]
    assert loss.item() > 0  # type: ignore[attr-defined]
    graphs, predicted = scope["graphs"], scope["predicted"]
    targets = len(graphs.target_node)  # type: ignore[attr-defined]
    assert predicted["AiGem"].shape == (targets, 25, 2)  # type: ignore[index]
    assert predicted["constant velocity"].shape == (targets, 25, 2)  # type: ignore[index]
    assert f"({targets}, 25, 2) ({targets}, 25, 2) ({targets}, 25, 2)" in out
