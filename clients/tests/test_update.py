"""The learner (sharedspace.train.update.SACUpdate) computes TorchRL's SACLoss: same losses and
same gradients on the same parameters, batch and random draws, for every built-in network."""

from __future__ import annotations

import copy

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from sac_reference import make_loss  # noqa: E402
from tensordict import TensorDict  # noqa: E402
from torchrl.data import Bounded  # noqa: E402

from sharedspace.train.config import TrainConfig  # noqa: E402
from sharedspace.train.networks import NETWORKS  # noqa: E402
from sharedspace.train.sac import make_actor, make_critic  # noqa: E402
from sharedspace.train.update import SACUpdate  # noqa: E402

B, M, F = 48, 8, 11


def replay_batch(gen: torch.Generator) -> TensorDict:
    """A replay batch with ragged masks (padding rows hold junk, as nothing may read them)."""

    def obs():
        mask = torch.rand(B, M, generator=gen) < 0.6
        mask[:, 0] = True
        return {
            "features": torch.randn(B, M, F, generator=gen) * 3,
            "adjacency": torch.rand(B, M, M, generator=gen),
            "mask": mask,
        }

    nxt = {
        **obs(),
        "reward": torch.randn(B, 1, generator=gen),
        "terminated": torch.rand(B, 1, generator=gen) < 0.2,
        "done": torch.rand(B, 1, generator=gen) < 0.3,
    }
    action = torch.rand(B, 2, generator=gen) * 2 - 1
    return TensorDict({**obs(), "action": action, "next": TensorDict(nxt, [B])}, [B])


def reference_and_update(variant: str, layer_norm: bool = False):
    """TorchRL's SACLoss and an SACUpdate holding the same actor and the same critic weights;
    the targets are moved away from the critics so that the target path is exercised."""
    cfg = TrainConfig(network=variant, gamma=0.97, critic_layer_norm=layer_norm)
    spec = Bounded(-1.0, 1.0, (2,))
    actor, critic = make_actor(cfg, spec), make_critic(cfg, spec)
    probe = replay_batch(torch.Generator().manual_seed(1))
    with torch.no_grad():
        critic(actor(probe))
        for m in critic.modules():  # off LayerNorm's initial affine (1, 0): both paths count
            if isinstance(m, torch.nn.LayerNorm):
                m.weight.add_(0.3 * torch.randn_like(m.weight))
                m.bias.add_(0.3 * torch.randn_like(m.bias))
    loss, _ = make_loss(cfg, actor, critic)
    with torch.no_grad():
        targets = loss.target_qvalue_network_params.flatten_keys(".")
        for name, p in targets.items():
            if not name.endswith("scale"):  # the feature scale is a constant buffer
                p.add_(0.05 * torch.randn_like(p))
        loss.log_alpha.fill_(-0.7)
    qnets, targets = [], []
    for params, out in (
        (loss.qvalue_network_params, qnets),
        (loss.target_qvalue_network_params, targets),
    ):
        for e in range(2):
            c = copy.deepcopy(critic)
            params[e].to_module(c)
            out.append(c.module)
    update = SACUpdate(
        actor,
        qnets,
        gamma=cfg.algo.gamma,
        tau=cfg.algo.tau,
        lr=cfg.algo.lr,
        alpha_init=cfg.algo.alpha_init,
    )
    with torch.no_grad():
        update.target_critics.load_state_dict(
            SACUpdate(actor, targets, gamma=0, tau=0, lr=1, alpha_init=1).critics.state_dict()
        )
        update.log_alpha.fill_(-0.7)
    return loss, update, actor


@pytest.mark.parametrize("layer_norm", [False, True], ids=["plain", "layer_norm"])
@pytest.mark.parametrize("variant", [n for n, net in NETWORKS.items() if net.sac_label])
def test_losses_and_gradients_equal_torchrl_sacloss(variant, layer_norm):
    torch.manual_seed(0)
    loss, update, actor = reference_and_update(variant, layer_norm)

    batch = replay_batch(torch.Generator().manual_seed(2))
    torch.manual_seed(7)
    ref = loss(batch.clone())
    torch.manual_seed(7)
    new = update.losses(batch.clone())
    for key in ("loss_qvalue", "loss_actor", "loss_alpha", "alpha", "entropy"):
        assert torch.allclose(ref[key], new[key], rtol=1e-5, atol=1e-6), key

    def grads(total):
        for p in [*actor.parameters(), *update.parameters(), loss.log_alpha]:
            p.grad = None
        for p in loss.qvalue_network_params.values(True, True):
            p.grad = None
        total.backward()

    grads(ref["loss_qvalue"] + ref["loss_actor"] + ref["loss_alpha"])
    ref_actor = [p.grad.clone() for p in actor.parameters()]
    ref_alpha = loss.log_alpha.grad.clone()
    ref_critic = [s for s in _critic_grads_torchrl(loss)]
    grads(new["loss_qvalue"] + new["loss_actor"] + new["loss_alpha"])
    for a, b in zip(ref_actor, [p.grad for p in actor.parameters()], strict=True):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-6)
    assert torch.allclose(ref_alpha, update.log_alpha.grad, rtol=1e-5)
    new_critic = _critic_grads_update(update)
    assert len(ref_critic) == len(new_critic)
    for e in range(2):
        for name, g in ref_critic[e].items():
            assert torch.allclose(g, new_critic[e][name], rtol=1e-4, atol=1e-6), (e, name)


def _critic_grads_torchrl(loss) -> list[dict[str, torch.Tensor]]:
    """Per critic, QNet parameter name -> gradient of SACLoss's stacked critic parameters."""
    flat = loss.qvalue_network_params.flatten_keys(".")
    out: list[dict[str, torch.Tensor]] = [{}, {}]
    for key, p in flat.items():
        if key.endswith("scale"):  # a buffer
            continue
        name = key.removeprefix("module.")
        for e in range(2):
            out[e][name] = p.grad[e].clone()
    return out


def _critic_grads_update(update: SACUpdate) -> list[dict[str, torch.Tensor]]:
    """The same from the ensemble: its gradients laid out as QNet state dicts."""
    ens = update.critics
    grads = copy.deepcopy(ens)
    with torch.no_grad():
        for p, g in zip(grads.parameters(), ens.parameters(), strict=True):
            p.copy_(g.grad)
    return grads.qnet_state_dicts()


def test_step_trains_in_place_and_round_trips_through_state_dict():
    loss, update, actor = reference_and_update("g_sac_cog")
    batch = replay_batch(torch.Generator().manual_seed(3))
    before = [p.detach().clone() for p in actor.parameters()]
    targets = [p.detach().clone() for p in update.target_critics.parameters()]
    out = update.step(batch)
    assert all(torch.isfinite(v).all() for v in out.values())
    assert any(not torch.equal(a, p) for a, p in zip(before, actor.parameters(), strict=True))
    for t0, t1, c in zip(
        targets, update.target_critics.parameters(), update.critics.parameters(), strict=True
    ):  # soft update: t1 = t0 + tau (c - t0)
        assert torch.allclose(t1, t0 + 0.005 * (c - t0), atol=1e-7)
    twin = reference_and_update("g_sac_cog")[1]
    twin.load_state_dict(update.state_dict())
    twin.load_optimizer_state(update.optimizer_state())
    for a, b in zip(twin.state_dict().values(), update.state_dict().values(), strict=True):
        assert torch.equal(a, b)
