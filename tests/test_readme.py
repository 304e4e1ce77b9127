"""The README's Python quick start, run as written, all its blocks one after the other, against a
tiny build and run laid out as the README's commands leave them (demo/build, demo/run); each block
alone runs in tests/test_docs.py, with every other code block of the docs."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_docs import code_blocks, run_python

README = "README.md"


def quick_start_blocks():  # noqa: ANN201
    """The Python code blocks of the README (its "Python quick start" section), in order."""
    return [block for block in code_blocks("python") if block.page == README]


def test_the_quick_start_has_the_promised_parts() -> None:
    code = "\n".join(block.code for block in quick_start_blocks())
    for part in ("open_build(", "DataLoader(", "loss.backward()", "predict_samples(", "PygLoader("):
        assert part in code
    assert 'load_model("demo/run")' in code  # as code, not in a comment: it runs


def test_the_quick_start_runs_as_written(docs_demo: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(docs_demo)
    scope, out = run_python(quick_start_blocks())
    assert "torch.Size([" in out
    loss = scope["loss"]
    assert loss.item() > 0  # type: ignore[attr-defined]
    graphs, predicted = scope["graphs"], scope["predicted"]
    targets = len(graphs.target_node)  # type: ignore[attr-defined]
    assert predicted["AiGem"].shape == (targets, 25, 2)  # type: ignore[index]
    assert predicted["constant velocity"].shape == (targets, 25, 2)  # type: ignore[index]
    assert f"({targets}, 25, 2) ({targets}, 25, 2) ({targets}, 25, 2)" in out
    assert scope["trained"].config == scope["config"]  # type: ignore[attr-defined]
