"""Several AiGem models of one ModelConfig trained as one (docs/aigem.md): an ensemble.

The M members' parameters are stacked along a leading member dimension under AiGem's own names
(`params["decoder.weight_ih"]` is (M, 3H, H)) and run through AiGem's one forward pass,
`aigem.model.network.forward_members`, which computes every operator once for all members. Member m
computes what `AiGem.forward(batch, steps[m])` computes, to float rounding:

- `forward` returns (M, A, K, 2) for K = max(steps); member m's positions after its own steps
  are zeros, not predictions. A model alone is an ensemble of one.
- `member_losses` is each member's `aigem.model.loss.masked_mse_m2` over its own steps; their sum's
  gradient in a member's parameters is that member's own loss gradient, and Adam, elementwise,
  steps the stacked parameters as M Adams would step each member's.
- Dropout: the members draw one mask from the global generator, the one each would draw trained
  alone (aigem.model.network draws it so for a model alone too, on every device): a fit's models start
  every epoch from one seed, and their encoders draw the same shapes.

`stack` and `unstack` move the members' parameters and their Adam states in and out (through the
optimisers' public `state_dict`): a fit stacks its models once and unstacks them only to write
each one's checkpoint, which stays each member's own.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from aigem.config import ModelConfig
from aigem.model.batch import Batch
from aigem.model.loss import member_sums
from aigem.model.network import AiGem, Decode, Params, decode_members, forward_members
from aigem.training.schedule import clip_gradients
from ngsim_graphs.scaling import MinMaxScaler


class Ensemble(nn.Module):
    """M AiGem models of one ModelConfig with stacked parameters; `steps[m]`: member m's future
    steps (ascending). A module (DistributedDataParallel wraps it), its parameters the stacked
    ones in AiGem's order; `params` holds them by AiGem's names."""

    def __init__(
        self,
        params: Params,
        config: ModelConfig,
        steps: Sequence[int],
        decode: Decode | None = None,
    ) -> None:
        super().__init__()
        if list(steps) != sorted(steps) or not steps:
            raise ValueError(f"an ensemble's members' steps must be ascending, not {list(steps)}")
        self.config, self.steps = config, tuple(steps)
        self.decode = decode or decode_members
        with torch.device("meta"):  # the parameters' names and order, on no memory,
            template = AiGem(config)  # drawing nothing from the global stream
        self.names = [name for name, _ in template.named_parameters()]
        if sorted(self.names) != sorted(params):
            raise ValueError("the stacked parameters are not AiGem's")
        # registered in AiGem's order (a module's names hold no dots: a list of them)
        self.stacked = nn.ParameterList([nn.Parameter(params[name]) for name in self.names])
        self.params: Params = dict(zip(self.names, self.stacked, strict=True))

    @property
    def members(self) -> int:
        return len(self.steps)

    def forward(self, batch: Batch) -> torch.Tensor:
        """(M, A, K, 2) scaled predicted positions of the batch's targets, K = max(steps)."""
        return forward_members(
            self.params, self.config, batch, self.steps, self.training, self.decode
        )

    def predict(self, batch: Batch) -> torch.Tensor:
        """`forward`'s (M, A, K, 2) in evaluation (validation, scoring): on the CPU the members
        one after the other (`predict_one_by_one`), faster there; elsewhere stacked."""
        if batch.x.device.type == "cpu":
            return self.predict_one_by_one(batch)
        return self(batch)

    def predict_one_by_one(self, batch: Batch) -> torch.Tensor:
        """`forward`'s (M, A, K, 2), the members run one after the other (M = 1 each, member m
        over its own steps): the same numbers to float rounding, and on the CPU faster than the
        stacked pass at evaluation's batches (docs/benchmarks.md). Evaluation only: in training each
        member would draw dropout masks of its own, not the stacked pass's."""
        if self.training:
            raise ValueError("predict_one_by_one is evaluation's: call eval() first")
        longest, outputs = max(self.steps), []
        for member, steps in enumerate(self.steps):
            params = {name: p[member : member + 1] for name, p in self.params.items()}
            out = forward_members(params, self.config, batch, (steps,), False, self.decode)
            outputs.append(F.pad(out, (0, 0, 0, longest - steps)))
        return torch.cat(outputs)

    def member_sums(
        self, model_out: torch.Tensor, batch: Batch, scaler: MinMaxScaler
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(M,) each member's squared error in metres^2 summed over its valid target steps, and
        (M,) their count (aigem.model.loss); `model_out` (M, A, K, 2) scaled."""
        return member_sums(model_out, batch, scaler, self.steps)

    def member_losses(
        self, model_out: torch.Tensor, batch: Batch, scaler: MinMaxScaler
    ) -> torch.Tensor:
        """(M,) each member's `aigem.model.loss.masked_mse_m2` over its own steps, in metres^2."""
        squared, count = self.member_sums(model_out, batch, scaler)
        return squared / count.clamp(min=1.0)

    def clip_gradients(self, max_norm: float | None) -> None:
        """`torch.nn.utils.clip_grad_norm_` of each member over its own gradients (None: none;
        aigem.training.schedule.clip_gradients)."""
        clip_gradients(self.parameters(), max_norm)


# -------------------------------------------------------------------------------------------------
# In and out: members' parameters and Adam states


def stack(models: Sequence[AiGem], steps: Sequence[int]) -> Ensemble:
    """An ensemble of copies of `models` (one ModelConfig), member m with `steps[m]` steps; it
    decodes as the first model does (compiled or not)."""
    configs = {model.config for model in models}
    if len(configs) != 1:
        raise ValueError("an ensemble's members share one ModelConfig")
    params, _ = torch.func.stack_module_state(list(models))
    return Ensemble(params, models[0].config, steps, models[0].decode_fn)


def unstack(ensemble: Ensemble, models: Sequence[AiGem]) -> None:
    """Copy each member's parameters back into its model (the model's own tensors, so that its
    optimiser still holds them)."""
    with torch.no_grad():
        for index, model in enumerate(models):
            for name, parameter in model.named_parameters():
                parameter.copy_(ensemble.params[name][index])


def stack_optimizer(
    ensemble: Ensemble, optimizers: Sequence[torch.optim.Optimizer], capturable: bool = False
) -> torch.optim.Optimizer:
    """One optimiser of the members' kind and settings over the ensemble's parameters, holding
    their states stacked. The members' optimisers are of one kind, have one parameter group each,
    with the same settings but for the learning rate (which the training loop sets before each
    step), and have taken the same number of steps: a step count, a 0-d state, is shared.
    `capturable`: an optimiser whose step a CUDA graph can capture (Adam's `capturable`, its
    learning rate a device tensor: aigem.training.engine)."""
    saved = [optimizer.state_dict() for optimizer in optimizers]
    groups = saved[0]["param_groups"]
    if any(len(s["param_groups"]) != 1 for s in saved):
        raise ValueError("an ensemble's members' optimisers have one parameter group each")
    if len({type(optimizer) for optimizer in optimizers}) != 1:
        raise ValueError("an ensemble's members' optimisers are of one kind")
    first = groups[0]
    for other in (s["param_groups"][0] for s in saved[1:]):
        for key in sorted((first.keys() | other.keys()) - {"params", "lr"}):
            if first.get(key) != other.get(key):
                raise ValueError(f"the members' optimisers differ in {key!r}")
    state = {}
    for index in saved[0]["state"]:
        entries = [s["state"][index] for s in saved]
        state[index] = {}
        for key, value in entries[0].items():
            values = [entry[key] for entry in entries]
            if value.dim() > 0:
                state[index][key] = torch.stack(values)
            elif all(torch.equal(value, other) for other in values):
                state[index][key] = value.clone()
            else:
                raise ValueError(f"the members' optimisers differ in {key!r}")
    settings = dict(optimizers[0].defaults)
    if capturable:
        device = next(ensemble.parameters()).device
        lr = torch.tensor(float(groups[0]["lr"]), dtype=torch.float32, device=device)
        settings |= {"capturable": True, "lr": lr}
        groups = [{**groups[0], "capturable": True, "lr": lr}]
    optimizer = type(optimizers[0])(ensemble.parameters(), **settings)
    optimizer.load_state_dict({"state": state, "param_groups": groups})
    return optimizer


def unstack_optimizer(
    stacked: torch.optim.Optimizer,
    optimizers: Sequence[torch.optim.Optimizer],
    rate: float | None = None,
) -> None:
    """Load each member's share of the ensemble's optimiser state into its own optimiser, which
    keeps its own settings but for the learning rate of the last step: `rate` (a number; None:
    the stacked optimiser's, which a capturable one holds as a float32 tensor)."""
    saved = stacked.state_dict()
    rate = float(stacked.param_groups[0]["lr"]) if rate is None else rate
    for member, optimizer in enumerate(optimizers):
        state = {
            index: {
                key: (value[member] if value.dim() > 0 else value).clone()
                for key, value in entry.items()
            }
            for index, entry in saved["state"].items()
        }
        groups = [{**optimizer.state_dict()["param_groups"][0], "lr": rate}]
        optimizer.load_state_dict({"state": state, "param_groups": groups})
