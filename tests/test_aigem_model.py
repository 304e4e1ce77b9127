"""AiGem's shapes, parameter count and decoder recursion."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch
from torch.func import functional_call
from torch_geometric.nn import GATConv

from aigem.config import ModelConfig
from aigem.model.batch import Batch, Edges
from aigem.model.network import NEGATIVE_SLOPE, AiGem, GATParameters, count_parameters


def tiny_batch(cv_step: torch.Tensor | None = None) -> Batch:
    torch.manual_seed(0)
    x = torch.randn(7, 4)
    spatial = Edges(torch.tensor([[0, 1, 0, 2, 4, 5], [1, 0, 2, 0, 5, 4]]), torch.rand(6, 1))
    temporal = Edges(torch.tensor([[0, 1], [4, 5]]), torch.full((2, 1), 0.2))
    targets = torch.tensor([5, 6])
    return Batch(
        x=x,
        target_node=targets,
        target_sample=torch.zeros(2, dtype=torch.long),
        target_xy=torch.zeros(2, 25, 2),
        target_mask=torch.ones(2, 25, dtype=torch.bool),
        edges={"spatial": spatial, "temporal": temporal},
        cv_step=cv_step,
        graphs=1,
    )


def test_parameter_count_is_within_5_percent_of_the_paper() -> None:
    # L=4 encoder: 2 GATs (576 / 4,416) + linear (320 / 4,160) per layer = 40,448;
    # GRU cell 64->64: 24,960; MLP 66->128->2: 8,834.
    assert count_parameters(AiGem(ModelConfig())) == 74_242
    assert abs(74_242 - 74_500) / 74_500 < 0.05
    assert count_parameters(AiGem(ModelConfig(concat_position=False))) == 74_242 - 2 * 128


def test_output_shapes_and_horizon() -> None:
    model = AiGem(ModelConfig()).eval()
    batch = tiny_batch()
    assert model(batch).shape == (2, 25, 2)
    assert model(batch, steps=5).shape == (2, 5, 2)
    assert torch.allclose(
        model(batch, steps=5), model(batch)[:, :5]
    )  # a prefix of the long horizon


def test_decoder_follows_the_residual_recursion() -> None:
    model = AiGem(ModelConfig(dropout=0.0)).eval()
    z, start = torch.randn(3, 64), torch.randn(3, 2)
    out = model.decode(z, start, steps=4)
    gru, mlp = model.decoder, model.output
    h = torch.zeros(3, 64)
    g1 = gru(z, h)
    g2 = gru(z + g1, g1)
    g3 = gru(g2 + g1, g2)
    y1 = start + mlp(torch.cat([g1, start], -1))
    y2 = y1 + mlp(torch.cat([g2, y1], -1))
    y3 = y2 + mlp(torch.cat([g3, y2], -1))
    assert torch.allclose(out[:, :3], torch.stack([y1, y2, y3], 1), atol=1e-6)


def test_cv_residual_adds_constant_velocitys_step_to_every_step() -> None:
    # Without the position in the MLP's input, the MLP's outputs do not depend on the path.
    config = ModelConfig(dropout=0.0, concat_position=False, cv_residual=True)
    model = AiGem(config).eval()
    paper = AiGem(ModelConfig(dropout=0.0, concat_position=False)).eval()
    paper.load_state_dict(model.state_dict())  # the same parameters: none is added
    batch = tiny_batch(cv_step=torch.tensor([[0.01, 0.02], [-0.03, 0.5]]))
    k = torch.arange(1, 6, dtype=torch.float32)[None, :, None]
    expected = paper(batch, steps=5) + k * batch.cv_step[:, None, :]
    assert torch.allclose(model(batch, steps=5), expected, atol=1e-5)
    assert torch.equal(paper(batch, steps=5), paper(tiny_batch(), steps=5))  # ignores cv_step
    with pytest.raises(ValueError, match="cv_step"):
        model(tiny_batch())


def test_gradients_reach_every_parameter() -> None:
    model = AiGem(ModelConfig())
    model(tiny_batch()).sum().backward()
    assert all(p.grad is not None for p in model.parameters())


def _pyg_gatconv(features: int, config: ModelConfig) -> GATConv:
    """PyG's GATConv that AiGem's GATParameters of `features` inputs are the parameters of."""
    return GATConv(features, config.hidden, heads=config.heads, concat=False, edge_dim=1,
                   add_self_loops=False, negative_slope=NEGATIVE_SLOPE)  # fmt: skip


@pytest.mark.parametrize(("features", "heads"), [(4, 1), (64, 1), (64, 2)])
def test_gat_parameters_are_pyg_gatconvs_drawn_alike(features: int, heads: int) -> None:
    """Names, order, shapes and values of PyG's GATConv under one seed, and the generator left
    where PyG leaves it: a seed makes the model it made when AiGem held PyG's GATConvs."""
    config = ModelConfig(heads=heads)
    torch.manual_seed(7)
    ours, after_ours = GATParameters(features, config), torch.rand(4)
    torch.manual_seed(7)
    theirs, after_theirs = _pyg_gatconv(features, config), torch.rand(4)
    ours_sd, theirs_sd = ours.state_dict(), theirs.state_dict()
    assert list(ours_sd) == list(theirs_sd)
    assert all(torch.equal(ours_sd[name], theirs_sd[name]) for name in theirs_sd)
    assert ours_sd["lin.weight"].abs().max() > 0 and not ours_sd["bias"].any()  # drawn; zeros
    assert torch.equal(after_ours, after_theirs)


def test_the_model_is_made_without_importing_pyg() -> None:
    """PyG's import (which loads torch._dynamo) would add seconds to every aigem command."""
    code = (
        "import sys; from aigem.model.network import AiGem; from aigem.config import ModelConfig; "
        "AiGem(ModelConfig()); print('torch_geometric' in sys.modules, 'torch._dynamo' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["False", "False"]


def _reference_forward(model: AiGem, batch: Batch, steps: int) -> torch.Tensor:
    """The model through PyG's plain GATConv path on every node (no pruning, no sparse product),
    on the model's own parameters (functional_call: the gradients reach them)."""
    z = batch.x
    edges = batch.edge_inputs(model.config.edge_types)
    for index, layer in enumerate(model.encoder):
        total = None
        for conv, (edge_index, attr) in zip(layer.convs(), edges, strict=True):
            pyg = _pyg_gatconv(conv.lin.weight.shape[1], model.config).eval()
            gat = functional_call(pyg, dict(conv.named_parameters()), (z, edge_index, attr))
            total = gat if total is None else total + gat
        z = total + layer.linear(z)  # (N, H)
        if index < len(model.encoder) - 1:
            z = torch.relu(z)
    target = batch.target_node
    return model.decode(z[target], batch.x[target, :2], steps)


@pytest.mark.parametrize("sparse", [True, False], ids=["csr", "gather-scatter"])
def test_fast_encoder_equals_pyg_gatconv_on_a_real_batch(
    tiny_build, sparse: bool, monkeypatch: pytest.MonkeyPatch
) -> None:  # noqa: ANN001, F811
    """AiGem's forward (the attention summing inputs, projected after) against PyG's GATConv
    applied as the paper's layers, on the CPU's path and on the accelerators'."""
    from aigem.model import plan as aigem_plan
    from aigem.model.data import Collate, GraphDataset

    monkeypatch.setattr(aigem_plan, "CPU_SPARSE", sparse)

    dataset = GraphDataset(tiny_build, "train")
    batch = Collate(dataset.scaler)(dataset.__getitems__(list(range(min(8, len(dataset))))))
    for config in (
        ModelConfig(),
        ModelConfig(layers=2, heads=2),
        ModelConfig(concat_position=False),
    ):
        torch.manual_seed(1)
        model = AiGem(config).eval()
        with torch.no_grad():
            fast, slow = model(batch, 10), _reference_forward(model, batch, 10)
        assert torch.allclose(fast, slow, atol=1e-5, rtol=1e-5)
    model = AiGem(ModelConfig(dropout=0.0))
    fast_loss, slow_loss = (
        model(batch, 5).square().sum(),
        _reference_forward(model, batch, 5).square().sum(),
    )
    fast_grads = torch.autograd.grad(fast_loss, list(model.parameters()), allow_unused=True)
    slow_grads = torch.autograd.grad(slow_loss, list(model.parameters()), allow_unused=True)
    for a, b in zip(fast_grads, slow_grads, strict=True):
        if a is not None and b is not None:
            assert torch.allclose(a, b, atol=1e-4, rtol=1e-3)


def test_graphs_cut_to_the_steps_the_model_reads_give_the_same_output(tiny_build) -> None:  # noqa: ANN001, F811
    """Same predictions and same gradients, in training mode (dropout) too, for several L."""
    from aigem.model.data import Collate, GraphDataset

    whole = GraphDataset(tiny_build, "train")
    ids = list(range(min(8, len(whole))))
    whole_batch = Collate(whole.scaler)(whole.__getitems__(ids))
    for layers in (1, 2, 4):
        config = ModelConfig(layers=layers)
        assert config.history_steps_read == layers + 1
        cut = GraphDataset(tiny_build, "train", history_steps=config.history_steps_read)
        cut_batch = Collate(cut.scaler)(cut.__getitems__(ids))
        assert cut_batch.x.shape[0] < whole_batch.x.shape[0] / 2
        torch.manual_seed(3)
        model = AiGem(config)  # training mode: dropout on
        outputs, grads = [], []
        for batch in (whole_batch, cut_batch):
            torch.manual_seed(4)
            out = model(batch)
            outputs.append(out)
            grads.append(
                torch.autograd.grad(out.square().sum(), list(model.parameters()), allow_unused=True)
            )
        assert torch.equal(outputs[0], outputs[1])
        for a, b in zip(*grads, strict=True):
            assert (a is None and b is None) or torch.equal(a, b)
        # one step fewer and the output changes: the model does read the earliest kept step
        short = GraphDataset(tiny_build, "train", history_steps=layers)
        model.eval()
        with torch.no_grad():
            short_out = model(Collate(short.scaler)(short.__getitems__(ids)))
            assert not torch.allclose(short_out, model(whole_batch))


def test_the_decoder_is_compiled_on_cuda_by_default_and_when_asked() -> None:
    from aigem.config import TrainConfig

    assert TrainConfig().compiles_on("cuda") and not TrainConfig().compiles_on("cpu")
    assert TrainConfig(compile=True).compiles_on("cpu") and not TrainConfig(
        compile=False
    ).compiles_on("cuda")


@pytest.mark.slow
def test_the_compiled_decoder_equals_the_eager_one() -> None:
    """torch.compile on the CPU (a minute or so): same positions and gradients to float32 rounding."""
    results = []
    for compiled in (False, True):
        torch.manual_seed(0)
        model = AiGem(ModelConfig())
        if compiled:
            model.compile_decoder()
        z, start = torch.randn(5, 64, requires_grad=True), torch.randn(5, 2)
        out = model.decode(z, start, steps=25)
        grads = torch.autograd.grad(out.square().sum(), [z, *model.decoder.parameters()])
        results.append((out.detach(), grads))
    assert torch.allclose(results[0][0], results[1][0], atol=1e-5, rtol=1e-5)
    for a, b in zip(results[0][1], results[1][1], strict=True):
        assert torch.allclose(a, b, atol=1e-4, rtol=1e-4)


def _base_state_dict_keys(layers: int = 4) -> list[str]:
    """The state_dict keys of AiGem(ModelConfig()) as every earlier checkpoint holds them."""
    gat = ["att_src", "att_dst", "att_edge", "bias", "lin.weight", "lin_edge.weight"]
    keys = []
    for layer in range(layers):
        for kind in ("spatial", "temporal"):
            keys += [f"encoder.{layer}.{kind}.{name}" for name in gat]
        keys += [f"encoder.{layer}.linear.weight", f"encoder.{layer}.linear.bias"]
    keys += ["decoder.weight_ih", "decoder.weight_hh", "decoder.bias_ih", "decoder.bias_hh"]
    return keys + [f"output.{i}.{p}" for i in (0, 2) for p in ("weight", "bias")]


def test_checkpoints_keep_their_keys_and_outputs() -> None:
    """A state_dict saved before the edge types had one home loads, and predicts as it did."""
    torch.manual_seed(5)
    model = AiGem(ModelConfig()).eval()
    assert list(model.state_dict()) == _base_state_dict_keys()
    out = model(tiny_batch(), steps=3).detach()
    assert float(out.sum()) == pytest.approx(1.7010380029678345, abs=1e-6)
    first = [0.6205710768699646, -0.46159085631370544, 0.632907509803772, -0.5080237984657288]
    assert out[0, :2].reshape(-1).tolist() == pytest.approx(first, abs=1e-6)
    assert out[1, 2].tolist() == pytest.approx([-0.1647607535123825, 0.49213117361068726], abs=1e-6)
    again = AiGem(ModelConfig()).eval()
    again.load_state_dict(dict(model.state_dict()), strict=True)
    assert torch.equal(again(tiny_batch(), steps=3), out)
