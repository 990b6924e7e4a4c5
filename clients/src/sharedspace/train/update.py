"""One SAC gradient step, written for the CPU: the learner's hot loop.

:class:`SACUpdate` computes exactly the losses of TorchRL's ``SACLoss`` (v2: two critics,
target critics, learned temperature with target entropy ``-|A|``, TD(0) target bootstrapped on
``terminated``) for the networks of :mod:`sharedspace.train.gcn`, and steps Adam on their sum as
the trainer always did. What it does differently is only how the arithmetic is laid out:

- **the critics are one ensemble** (:class:`CriticEnsemble`): their weights are stacked
  ``[E, in, out]`` and every layer is one batched matmul; the first GCN layer, whose input is
  shared, is one matmul against the concatenated weights, and so is its aggregation;
- **shared inputs are computed once**: the scaled features and normalised adjacency of the
  observation (and of the next one) feed the actor and both critics; the critics' graph
  embedding of the observation and its part of the first head layer serve both the critic loss
  and the actor loss (the actor loss sees them detached, as ``SACLoss`` sees detached critic
  parameters);
- no TensorDict plumbing or ``vmap`` inside the step, and Adam's fused CPU kernel.

``clients/tests/test_update.py`` checks, for every network, that the losses and every gradient
equal ``SACLoss``'s on the same parameters, batch and random draws; ``benchmarks/sac_update.py``
times both side by side (docs/BENCHMARKS.md).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.modules.distributions import TanhNormal
from torchrl.modules.distributions.utils import rsample_and_log_prob

from sharedspace.train.gcn import GraphEncoder, QNet, aggregate

__all__ = ["CriticEnsemble", "SACUpdate", "actor_net_of"]


def _stack(tensors: Sequence[torch.Tensor]) -> nn.Parameter:
    return nn.Parameter(torch.stack([t.detach().clone() for t in tensors]))


class CriticEnsemble(nn.Module):
    """``E`` critics :class:`~sharedspace.train.gcn.QNet` of one architecture with their
    weights stacked along a leading ensemble dimension. Weights are stored transposed
    (``[E, in, out]``) so that each layer is a batched ``x @ W``.

    Built from ``E`` independently initialised :class:`QNet` (the same initialisation as
    separate critics), and convertible back with :meth:`qnet_state_dicts`.
    """

    def __init__(self, qnets: Sequence[QNet]):
        super().__init__()
        enc: GraphEncoder = qnets[0].encoder
        self.graph = enc.graph
        self.readout = enc.readout
        self.size = len(qnets)
        if self.graph is None:
            self.enc_w = nn.ParameterList([_stack([q.encoder.flat[0].weight.T for q in qnets])])
            self.enc_b = nn.ParameterList([_stack([q.encoder.flat[0].bias for q in qnets])])
        else:
            n = len(enc.layers)
            self.enc_w = nn.ParameterList(
                [_stack([q.encoder.layers[i].linear.weight.T for q in qnets]) for i in range(n)]
            )
            self.enc_b = nn.ParameterList(
                [_stack([q.encoder.layers[i].bias for q in qnets]) for i in range(n)]
            )
        linears = [[m for m in q.head if isinstance(m, nn.Linear)] for q in qnets]
        self.head_w = nn.ParameterList(
            [_stack([ls[i].weight.T for ls in linears]) for i in range(len(linears[0]))]
        )
        self.head_b = nn.ParameterList(
            [_stack([ls[i].bias for ls in linears]) for i in range(len(linears[0]))]
        )
        # The head's module indices (QNet state-dict names) and, with LayerNorm, its affine
        # weights after each hidden Linear.
        self._linear_at = [i for i, m in enumerate(qnets[0].head) if isinstance(m, nn.Linear)]
        self._norm_at = [i for i, m in enumerate(qnets[0].head) if isinstance(m, nn.LayerNorm)]
        norms = [[m for m in q.head if isinstance(m, nn.LayerNorm)] for q in qnets]
        self.norm_w = nn.ParameterList(
            [_stack([ns[i].weight for ns in norms]) for i in range(len(self._norm_at))]
        )
        self.norm_b = nn.ParameterList(
            [_stack([ns[i].bias for ns in norms]) for i in range(len(self._norm_at))]
        )
        self.embed_features = self.head_w[0].shape[1] - self._action_dim(qnets[0])

    @staticmethod
    def _action_dim(q: QNet) -> int:
        return q.head[0].in_features - q.encoder.out_features

    def qnet_state_dicts(self) -> list[dict[str, torch.Tensor]]:
        """The ensemble as ``E`` :class:`QNet` state dicts (layer names of ``QNet``)."""
        out = []
        for e in range(self.size):
            sd: dict[str, torch.Tensor] = {}
            if self.graph is None:
                sd["encoder.flat.0.weight"] = self.enc_w[0][e].T.detach().clone()
                sd["encoder.flat.0.bias"] = self.enc_b[0][e].detach().clone()
            else:
                for i, (w, b) in enumerate(zip(self.enc_w, self.enc_b, strict=True)):
                    sd[f"encoder.layers.{i}.linear.weight"] = w[e].T.detach().clone()
                    sd[f"encoder.layers.{i}.bias"] = b[e].detach().clone()
            for at, w, b in zip(self._linear_at, self.head_w, self.head_b, strict=True):
                sd[f"head.{at}.weight"] = w[e].T.detach().clone()
                sd[f"head.{at}.bias"] = b[e].detach().clone()
            for at, w, b in zip(self._norm_at, self.norm_w, self.norm_b, strict=True):
                sd[f"head.{at}.weight"] = w[e].detach().clone()
                sd[f"head.{at}.bias"] = b[e].detach().clone()
            out.append(sd)
        return out

    def embed(self, h: torch.Tensor, a_hat: torch.Tensor | None, m: torch.Tensor) -> torch.Tensor:
        """Every critic's graph embedding ``[E, B, D]`` of prepared inputs
        (:meth:`GraphEncoder.prepare`: ``h [B, M, F]``, ``a_hat [B, M, M]``, ``m [B, M, 1]``)."""
        e = self.size
        if self.graph is None:
            x = torch.cat([h, m], -1).flatten(-2)  # [B, M (F + 1)], shared by every critic
            w, b = self.enc_w[0][:, : x.shape[-1]], self.enc_b[0]  # dropped padding: zeros
            y = x @ w.permute(1, 0, 2).reshape(w.shape[1], -1) + b.reshape(-1)
            return torch.relu_(y).reshape(x.shape[0], e, -1).transpose(0, 1)
        batch, nodes, _ = h.shape
        # The critics' node embeddings stay side by side, [B, M, E H]: the first layer's input is
        # shared, so its weights are concatenated, and a later layer's weights form one
        # block-diagonal matrix; a_hat mixes nodes only, so one aggregation serves every critic.
        x = h
        for w, b in zip(self.enc_w, self.enc_b, strict=True):
            weight = w.permute(1, 0, 2).reshape(w.shape[1], -1) if x is h else torch.block_diag(*w)
            x = torch.relu_(aggregate(x, a_hat, weight, b.reshape(-1)))
        ego = x[:, 0].reshape(batch, e, -1).transpose(0, 1)
        if self.readout == "ego":
            return ego
        count = m.sum(-2).clamp_min(1.0)  # [B, 1]
        mean = (m.transpose(-1, -2) @ x).reshape(batch, e, -1).transpose(0, 1) / count
        return torch.cat([ego, mean], -1)

    def first_layer(self, embedding: torch.Tensor) -> torch.Tensor:
        """The embedding's part of the first head layer, bias included: ``[E, B, H]``."""
        w = self.head_w[0][:, : self.embed_features]
        return torch.baddbmm(self.head_b[0].unsqueeze(1), embedding, w)

    def q_values(
        self, first: torch.Tensor, action: torch.Tensor, detach_params: bool = False
    ) -> torch.Tensor:
        """``Q [E, B]`` from :meth:`first_layer`'s output and the action ``[B, A]``; with
        ``detach_params`` no gradient reaches the critics' weights (only the action's)."""
        ws = [w.detach() if detach_params else w for w in self.head_w]
        bs = [b.detach() if detach_params else b for b in self.head_b]
        # in-place ReLUs: the matmuls' backward does not need their outputs, and a fresh
        # [E, B, H] buffer per activation costs more than the arithmetic on this CPU
        w_action = ws[0][:, self.embed_features :]
        x = torch.baddbmm(first, action.expand(self.size, *action.shape), w_action)
        x = torch.relu_(self._norm(x, 0, detach_params))
        for i, (w, b) in enumerate(zip(ws[1:-1], bs[1:-1], strict=True)):
            x = torch.relu_(self._norm(torch.baddbmm(b.unsqueeze(1), x, w), i + 1, detach_params))
        return torch.baddbmm(bs[-1].unsqueeze(1), x, ws[-1]).squeeze(-1)

    def _norm(self, x: torch.Tensor, i: int, detach_params: bool) -> torch.Tensor:
        """The ``i``-th hidden layer's LayerNorm (per critic affine weights), if any."""
        if not self._norm_at:
            return x
        w, b = self.norm_w[i], self.norm_b[i]
        if detach_params:
            w, b = w.detach(), b.detach()
        x = nn.functional.layer_norm(x, x.shape[-1:])
        return torch.addcmul(b.unsqueeze(1), x, w.unsqueeze(1))

    def forward(self, h, a_hat, m, action) -> torch.Tensor:
        """``Q [E, B]`` of prepared inputs and actions."""
        return self.q_values(self.first_layer(self.embed(h, a_hat, m)), action)


def actor_net_of(actor) -> nn.Module:
    """The plain module inside the trainer's ``ProbabilisticActor`` (``sac.make_actor``):
    observation keys in, ``(loc, scale)`` out."""
    return actor.module[0].module


class SACUpdate(nn.Module):
    """Parameters, target critics, optimisers and one gradient step of SAC.

    Args:
        actor: the trainer's ``ProbabilisticActor`` (its weights are trained in place, so the
            collector and the evaluation keep using it).
        qnets: ``E`` freshly initialised :class:`QNet` critics (weights are copied).
        gamma, tau, lr, alpha_init, loss_function: as
            :class:`~sharedspace.train.algorithm_configs.SacConfig`.
        action_dim: ``|A|``; the target entropy is ``-action_dim``.
    """

    def __init__(
        self,
        actor,
        qnets: Sequence[QNet],
        *,
        gamma: float,
        tau: float,
        lr: float,
        alpha_init: float,
        loss_function: str = "l2",
        action_dim: int = 2,
        bc_weight: float = 0.0,
        residual: bool = False,
    ):
        super().__init__()
        if loss_function not in ("l2", "smooth_l1"):
            raise ValueError(f"loss_function must be l2 or smooth_l1, not {loss_function!r}")
        self.actor = actor_net_of(actor)
        self.critics = CriticEnsemble(qnets)
        self.target_critics = copy.deepcopy(self.critics).requires_grad_(False)
        self.log_alpha = nn.Parameter(torch.tensor(math.log(alpha_init)))
        self.gamma, self.tau, self.bc_weight = gamma, tau, bc_weight
        self.residual = residual
        self.loss_function = loss_function
        self.target_entropy = -float(action_dim)
        fused = {"fused": True} if _fused_adam_ok(self.log_alpha.device) else {}
        self.optimizers = {
            "actor": torch.optim.Adam(self.actor.parameters(), lr=lr, **fused),
            "critic": torch.optim.Adam(self.critics.parameters(), lr=lr, **fused),
            "alpha": torch.optim.Adam([self.log_alpha], lr=lr, **fused),
        }

    def _policy(self, h, a_hat, m) -> TanhNormal:
        return TanhNormal(*self._policy_params(h, a_hat, m), low=-1.0, high=1.0, tanh_loc=False)

    def _policy_params(self, h, a_hat, m) -> tuple[torch.Tensor, torch.Tensor]:
        """The actor's ``(loc, scale)``: its deterministic action is ``tanh(loc)``."""
        net = self.actor.net
        return self.actor.extract(net.head(net.encoder.embed(h, a_hat, m)))

    def losses(self, batch: TensorDictBase, bc_rows: int = 0) -> dict[str, torch.Tensor]:
        """SACLoss's ``loss_qvalue``, ``loss_actor``, ``loss_alpha`` (with graphs), ``alpha``
        and ``entropy`` on a replay batch. Random draws in SACLoss's order: the next actions
        (target) first, then the actions of the actor loss.

        With ``bc_weight`` > 0 and ``bc_rows`` > 0 (the batch's first rows are prior data of
        successful episodes) the actor loss adds TD3+BC's term: ``bc_weight * mean|Q|``
        (detached) times the squared distance of the policy's deterministic action
        ``tanh(loc)`` to the recorded one on those rows, so that the weight does not depend on
        the scale of the returns. A ``residual`` learner (the actor's action adds to a scripted
        driver's) imitates the script itself on every other row: the term pulls ``tanh(loc)``
        toward the recorded residual on the prior rows and toward 0 on the rest."""
        encoder = self.actor.net.encoder
        nxt = batch["next"]
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            h1, a1, m1 = encoder.prepare(nxt["features"], nxt["adjacency"], nxt["mask"])
            next_action, next_log_prob = rsample_and_log_prob(self._policy(h1, a1, m1))
            next_q = self.target_critics(h1, a1, m1, next_action)  # [E, B]
            next_value = (next_q - alpha * next_log_prob).min(0)[0]
            not_terminated = 1.0 - nxt["terminated"].reshape(-1).to(next_value.dtype)
            target = nxt["reward"].reshape(-1) + self.gamma * not_terminated * next_value

        h, a_hat, m = encoder.prepare(batch["features"], batch["adjacency"], batch["mask"])
        first = self.critics.first_layer(self.critics.embed(h, a_hat, m))
        pred = self.critics.q_values(first, batch["action"])
        if self.loss_function == "l2":
            loss_q = (pred - target).square().sum(0).mean()
        else:
            loss_q = (
                nn.functional.smooth_l1_loss(pred, target.expand_as(pred), reduction="none")
                .sum(0)
                .mean()
            )

        loc, scale = self._policy_params(h, a_hat, m)
        policy = TanhNormal(loc, scale, low=-1.0, high=1.0, tanh_loc=False)
        action, log_prob = rsample_and_log_prob(policy)
        q_new = self.critics.q_values(first.detach(), action, detach_params=True).min(0)[0]
        loss_actor = (alpha * log_prob - q_new).mean()
        out = {}
        if self.bc_weight > 0 and (bc_rows > 0 or self.residual):
            if self.residual:  # the recorded residual on prior rows, the script's (0) elsewhere
                wanted = torch.zeros_like(loc)
                wanted[:bc_rows] = batch["action"][:bc_rows]
                loss_bc = (torch.tanh(loc) - wanted).square().sum(-1).mean()
            else:
                mode = torch.tanh(loc[:bc_rows])
                loss_bc = (mode - batch["action"][:bc_rows]).square().sum(-1).mean()
            loss_actor = loss_actor + self.bc_weight * q_new.detach().abs().mean() * loss_bc
            out["loss_bc"] = loss_bc.detach()
        loss_alpha = (-self.log_alpha * (log_prob.detach() + self.target_entropy)).mean()
        return {
            "loss_qvalue": loss_q,
            "loss_actor": loss_actor,
            "loss_alpha": loss_alpha,
            "alpha": alpha,
            "entropy": -log_prob.detach().mean(),
            **out,
        }

    def step(
        self, batch: TensorDictBase, bc_rows: int = 0, train_actor: bool = True
    ) -> dict[str, torch.Tensor]:
        """One gradient step on ``batch`` (its first ``bc_rows`` rows prior data) and the soft
        target update; returns the losses. With ``train_actor`` False only the critics learn
        (a critic warm-up: a started actor is not steered by untrained critics)."""
        out = self.losses(batch, bc_rows)
        for o in self.optimizers.values():
            o.zero_grad(set_to_none=True)
        # Each loss reaches only its own network's weights (the actor loss sees detached critic
        # weights, the alpha loss a detached log-prob), so one backward of the sum suffices.
        (out["loss_qvalue"] + out["loss_actor"] + out["loss_alpha"]).backward()
        for name, o in self.optimizers.items():
            if train_actor or name == "critic":
                o.step()
        self.update_targets()
        return out

    def clone_step(self, batch: TensorDictBase) -> torch.Tensor:
        """One behaviour-cloning step of the actor alone; returns the squared distance of its
        deterministic action ``tanh(loc)`` to the recorded ``action``, which the step descends.

        The step also fits the policy's ``scale`` to what the clone still misses: the Gaussian
        negative log-likelihood of the recorded action (before the tanh) around the detached
        ``loc``. So the cloned policy explores about as far as it is unsure, rather than at the
        initial scale of about 1 that would bury the clone in noise."""
        encoder = self.actor.net.encoder
        h, a_hat, m = encoder.prepare(batch["features"], batch["adjacency"], batch["mask"])
        loc, scale = self._policy_params(h, a_hat, m)
        target = batch["action"]
        loss = (torch.tanh(loc) - target).square().sum(-1).mean()
        pre_tanh = torch.atanh(target.clamp(-0.999, 0.999))
        nll = (scale.log() + (pre_tanh - loc.detach()).square() / (2 * scale.square())).mean()
        self.optimizers["actor"].zero_grad(set_to_none=True)
        (loss + nll).backward()
        self.optimizers["actor"].step()
        return loss.detach()

    @torch.no_grad()
    def update_targets(self) -> None:
        """``theta' <- theta' + tau (theta - theta')`` (TorchRL's ``SoftUpdate``)."""
        target = list(self.target_critics.parameters())
        torch._foreach_lerp_(target, list(self.critics.parameters()), self.tau)

    def optimizer_state(self) -> dict[str, dict]:
        return {k: o.state_dict() for k, o in self.optimizers.items()}

    def load_optimizer_state(self, state: dict[str, dict]) -> None:
        for k, o in self.optimizers.items():
            o.load_state_dict(state[k])


def _fused_adam_ok(device: torch.device) -> bool:
    """Fused Adam runs on CPU and CUDA in the torch versions we pin; test it once."""
    try:
        p = nn.Parameter(torch.zeros(1, device=device))
        torch.optim.Adam([p], fused=True)
        return True
    except (RuntimeError, TypeError):
        return False
