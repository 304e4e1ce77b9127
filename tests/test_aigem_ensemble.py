"""The ensemble (aigem.training.ensemble): member m computes and learns what AiGem m alone would.

In float32 the ensemble's products sum in another order than each model's (batched products, one
block-diagonal graph, the scores as z . (W^T a)), so outputs agree to float32 rounding. Training
is compared in float64, where that rounding is ~1e-16: Adam divides each gradient by its own
running size, so float32 rounding in a gradient near zero becomes a difference of the order of
the learning rate in the step, and a float32 comparison of trained weights would measure that,
not the ensemble.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader

from aigem.config import ModelConfig
from aigem.model import plan as aigem_plan
from aigem.model.batch import Batch
from aigem.model.data import Collate, GraphDataset
from aigem.model.loss import masked_mse_m2
from aigem.model.network import AiGem
from aigem.training import ensemble

STEPS = (5, 10, 10, 25)  # ascending; two members of one horizon


@pytest.fixture(scope="module")
def data(tiny_build: Path) -> tuple[Batch, GraphDataset]:
    dataset = GraphDataset(tiny_build, "train", history_steps=ModelConfig().history_steps_read)
    loader = DataLoader(dataset, batch_size=8, collate_fn=Collate(dataset.scaler, layers=4))
    return next(iter(loader)), dataset


def _models(count: int, config: ModelConfig, dtype: torch.dtype = torch.float32) -> list[AiGem]:
    models = []
    for seed in range(count):  # members with other weights, so that a mix-up shows
        torch.manual_seed(seed)
        models.append(AiGem(config).to(dtype))
    return models


def test_cpu_dropout_is_a_bernoulli_mask_of_the_global_stream() -> None:
    """What the ensemble relies on to draw each member's masks as F.dropout would."""
    x = torch.randn(300, 7)
    torch.manual_seed(5)
    state = torch.get_rng_state()
    expected = F.dropout(x, p=0.3, training=True)
    after = torch.get_rng_state()
    generator = torch.Generator().set_state(state)
    mask = torch.empty_like(x).bernoulli_(0.7, generator=generator).div_(0.7)
    assert torch.equal(x * mask, expected)
    assert torch.equal(generator.get_state(), after)  # the stream moves on alike
    assert 0 < int((mask == 0).sum()) < x.numel()


@pytest.mark.parametrize("sparse", [True, False], ids=["csr", "gather-scatter"])
@pytest.mark.parametrize("training", [False, True], ids=["eval", "train"])
def test_each_member_computes_its_model(
    data: tuple[Batch, GraphDataset], sparse: bool, training: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    batch, _ = data
    monkeypatch.setattr(aigem_plan, "CPU_SPARSE", sparse)
    config = ModelConfig(dropout=0.3)
    models = _models(len(STEPS), config)
    stacked = ensemble.stack(models, STEPS).train(training)
    torch.manual_seed(7)
    out = stacked(batch)
    assert out.shape == (len(STEPS), len(batch.target_node), 25, 2)
    if training:  # evaluation's alone
        with pytest.raises(ValueError, match="evaluation"):
            stacked.predict_one_by_one(batch)
    one_by_one = stacked.eval().predict_one_by_one(batch)  # evaluation's path on the CPU
    for index, (model, steps) in enumerate(zip(models, STEPS, strict=True)):
        torch.manual_seed(7)  # the members' one stream: each draws the masks it draws alone
        alone = model.train(training)(batch, steps)
        torch.testing.assert_close(out[index, :, :steps], alone, rtol=1e-5, atol=1e-5)
        assert not out[index, :, steps:].any() and not one_by_one[index, :, steps:].any()
        if not training:  # one after the other: each member is its model alone, to the bit
            assert torch.equal(one_by_one[index, :, :steps], alone)
    if training:  # another stream, other masks, another output
        torch.manual_seed(11)
        assert not torch.allclose(models[1].train()(batch, 10), out[1, :, :10])


def test_members_losses_are_each_models_loss(data: tuple[Batch, GraphDataset]) -> None:
    batch, dataset = data
    out = torch.randn(len(STEPS), len(batch.target_node), 25, 2)
    stacked = ensemble.stack(_models(len(STEPS), ModelConfig()), STEPS)
    losses = stacked.member_losses(out, batch, dataset.scaler)
    for index, steps in enumerate(STEPS):
        alone = masked_mse_m2(out[index, :, :steps], batch, dataset.scaler, steps)
        assert torch.equal(losses[index], alone)  # bitwise: its checkpoints record its losses


@pytest.mark.parametrize("clip", [None, 0.5], ids=["no-clip", "clip"])
@pytest.mark.parametrize("sparse", [True, False], ids=["csr", "gather-scatter"])
@pytest.mark.parametrize(
    "config",
    [ModelConfig(dropout=0.2), ModelConfig(dropout=0.2, heads=2, layers=3)],
    ids=["paper", "two-heads-three-layers"],
)
def test_steps_of_the_ensemble_are_steps_of_each_model(
    data: tuple[Batch, GraphDataset],
    clip: float | None,
    sparse: bool,
    config: ModelConfig,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Three Adam steps with dropout on (and clipping) in float64: the stacked parameters, the
    Adam states and the losses are each model's trained alone on the members' dropout stream."""
    batch, dataset = data
    batch = batch.to(dtype=torch.float64)
    monkeypatch.setattr(aigem_plan, "CPU_SPARSE", sparse)
    models = _models(len(STEPS), config, torch.float64)
    alone_models = _models(len(STEPS), config, torch.float64)
    optimizers = [torch.optim.Adam(m.parameters(), lr=1e-2, fused=True) for m in models]
    alone_optimizers = [torch.optim.Adam(m.parameters(), lr=1e-2, fused=True) for m in alone_models]
    torch.manual_seed(21)
    streams = [torch.get_rng_state()] * len(STEPS)
    stacked = ensemble.stack(models, STEPS)
    optimizer = ensemble.stack_optimizer(stacked, optimizers)
    alone_losses = []
    for _ in range(3):
        torch.set_rng_state(streams[0])
        losses = stacked.member_losses(stacked(batch), batch, dataset.scaler)
        optimizer.zero_grad()
        losses.sum().backward()
        stacked.clip_gradients(clip)
        optimizer.step()
        after = torch.get_rng_state()
        row = []
        for index, (model, steps) in enumerate(zip(alone_models, STEPS, strict=True)):
            torch.set_rng_state(streams[index])
            loss = masked_mse_m2(model(batch, steps), batch, dataset.scaler, steps)
            streams[index] = torch.get_rng_state()
            alone_optimizers[index].zero_grad()
            loss.backward()
            if clip is not None:  # the reference: PyTorch's, of the model alone
                torch.nn.utils.clip_grad_norm_(model.parameters(), clip)
            alone_optimizers[index].step()
            row.append(loss.detach())
        torch.testing.assert_close(losses.detach(), torch.stack(row), rtol=1e-10, atol=0.0)
        alone_losses.append(row)
    ensemble.unstack(stacked, models)
    ensemble.unstack_optimizer(optimizer, optimizers)
    # Adam steps a weight by lr m / (sqrt(v) + 1e-8): where a gradient is zero but for rounding
    # (an att_dst whose scores leaky_relu keeps linear cancels in the softmax: ~1e-14), the
    # rounding / 1e-8 shows as up to ~1e-8 per step. A wrong step is off by the order of lr, 1e-2.
    # The next steps' gradients, taken at weights that far apart, differ by as much again (up to
    # ~3e-9 in the Adam moments of the synthetic batch): the states are held to the same bound.
    for model, alone in zip(models, alone_models, strict=True):
        torch.testing.assert_close(model.state_dict(), alone.state_dict(), rtol=1e-7, atol=1e-7)
    for mine, theirs in zip(optimizers, alone_optimizers, strict=True):
        torch.testing.assert_close(mine.state_dict(), theirs.state_dict(), rtol=1e-7, atol=1e-7)
        for stream in streams:
            assert torch.equal(after, stream)  # the stream moved on as each model's own
    assert float(alone_losses[-1][0]) != float(alone_losses[0][0])  # it did learn


def test_stack_and_unstack_round_trip(data: tuple[Batch, GraphDataset]) -> None:
    """Parameters and Adam states (after a step: moments and step counts) come back exactly."""
    batch, dataset = data
    models = _models(3, ModelConfig())
    optimizers = [torch.optim.Adam(m.parameters(), lr=1e-3, fused=True) for m in models]
    for model, optimizer in zip(models, optimizers, strict=True):
        masked_mse_m2(model(batch, 5), batch, dataset.scaler, 5).backward()
        optimizer.step()
    state = torch.get_rng_state()
    stacked = ensemble.stack(models, (5, 5, 5))
    optimizer = ensemble.stack_optimizer(stacked, optimizers)
    assert torch.equal(torch.get_rng_state(), state)  # stacking draws nothing
    assert stacked.params["decoder.weight_ih"].shape == (3, 3 * 64, 64)
    assert optimizer.state_dict()["state"][0]["exp_avg"].shape[0] == 3
    fresh = _models(3, ModelConfig())
    fresh_optimizers = [torch.optim.Adam(m.parameters(), lr=1.0, fused=True) for m in fresh]
    ensemble.unstack(stacked, fresh)
    ensemble.unstack_optimizer(optimizer, fresh_optimizers)
    for model, copy in zip(models, fresh, strict=True):
        for (name, value), (_, copied) in zip(
            model.state_dict().items(), copy.state_dict().items(), strict=True
        ):
            assert torch.equal(value, copied), name
    for mine, theirs in zip(optimizers, fresh_optimizers, strict=True):
        one, other = mine.state_dict(), theirs.state_dict()
        assert one["param_groups"] == other["param_groups"]  # lr 1e-3 back too
        for index, entry in one["state"].items():
            for key, value in entry.items():
                assert torch.equal(value, other["state"][index][key]), (index, key)


def test_members_that_differ_are_refused() -> None:
    with pytest.raises(ValueError, match="steps must be ascending"):
        ensemble.stack(_models(2, ModelConfig()), (10, 5))
    with pytest.raises(ValueError, match="share one ModelConfig"):
        ensemble.stack([AiGem(ModelConfig()), AiGem(ModelConfig(concat_position=False))], (5, 5))
    models = _models(2, ModelConfig())
    optimizers = [torch.optim.Adam(m.parameters()) for m in models]
    for model, optimizer, steps in zip(models, optimizers, (1, 2), strict=True):
        for parameter in model.parameters():
            parameter.grad = torch.zeros_like(parameter)
        for _ in range(steps):  # the second one step ahead
            optimizer.step()
    with pytest.raises(ValueError, match="differ in 'step'"):
        ensemble.stack_optimizer(ensemble.stack(models, (5, 5)), optimizers)


def test_members_optimisers_of_other_settings_are_refused() -> None:
    """Member 0's settings would silently be every member's: only the learning rate (set before
    each step) may differ."""
    models = _models(3, ModelConfig())
    stacked = ensemble.stack(models, (5, 5, 10))

    def adams(**last: object) -> list[torch.optim.Optimizer]:
        settings = [{}, {}, last]
        return [
            torch.optim.Adam(m.parameters(), **s) for m, s in zip(models, settings, strict=True)
        ]

    for key, value in [("betas", (0.8, 0.999)), ("weight_decay", 0.01), ("amsgrad", True)]:
        with pytest.raises(ValueError, match=f"the members' optimisers differ in '{key}'"):
            ensemble.stack_optimizer(stacked, adams(**{key: value}))
    optimizer = ensemble.stack_optimizer(stacked, adams(lr=0.5))
    assert optimizer.param_groups[0]["lr"] == 1e-3  # member 0's, until the loop sets it
    sgd = [*adams()[:2], torch.optim.SGD(models[2].parameters(), lr=1e-3)]
    with pytest.raises(ValueError, match="of one kind"):
        ensemble.stack_optimizer(stacked, sgd)


def test_a_gat_whose_lin_has_a_bias_is_refused() -> None:
    """The forward scores attention as z . (lin.weight^T att), which leaves out a bias of lin
    (PyG's GATConv has none): a model given one is refused, not computed without it."""
    models = _models(2, ModelConfig(layers=2))
    for model in models:
        conv = model.encoder[1].convs()[0]
        conv.lin.bias = torch.nn.Parameter(torch.ones(conv.lin.weight.shape[0]))
    with pytest.raises(ValueError, match="not AiGem's"):
        ensemble.stack(models, (5, 10))


@pytest.mark.parametrize(
    "config",
    [
        ModelConfig(concat_position=False),
        ModelConfig(cv_residual=True),
        ModelConfig(heads=2, layers=2),
    ],
    ids=["no-concat", "cv-residual", "two-heads"],
)
def test_each_member_computes_its_model_of_any_shape(
    data: tuple[Batch, GraphDataset], config: ModelConfig
) -> None:
    batch, _ = data
    models = [model.eval() for model in _models(2, config)]
    out = ensemble.stack(models, (5, 10)).eval()(batch)  # a plan of 4 layers: made again for 2
    for index, (model, steps) in enumerate(zip(models, (5, 10), strict=True)):
        torch.testing.assert_close(out[index, :, :steps], model(batch, steps), rtol=1e-5, atol=1e-5)
