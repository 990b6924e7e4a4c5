"""GCN normalisation by hand and the forward shapes of the three registered networks."""

from __future__ import annotations

import math

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from sac_reference import make_loss  # noqa: E402

from sharedspace.train.config import (  # noqa: E402
    TrainConfig,
    apply_overrides,
    load_config,
)
from sharedspace.train.envs import make_env  # noqa: E402
from sharedspace.train.gcn import (  # noqa: E402
    GCNLayer,
    GraphEncoder,
    normalized_adjacency,
    uniform_adjacency,
)
from sharedspace.train.networks import NETWORKS  # noqa: E402
from sharedspace.train.sac import make_actor, make_critic  # noqa: E402


def test_normalisation_by_hand_with_masking():
    # 3 present nodes + 1 padding node; asymmetric A; junk in the padding row/col and diagonal.
    a = torch.tensor(
        [
            [9.0, 1.0, 0.5, 7.0],
            [2.0, 9.0, 0.0, 7.0],
            [0.0, 3.0, 9.0, 7.0],
            [7.0, 7.0, 7.0, 7.0],
        ]
    )
    mask = torch.tensor([True, True, True, False])
    got = normalized_adjacency(a, mask)
    at = [[1.0, 1.0, 0.5], [2.0, 1.0, 0.0], [0.0, 3.0, 1.0]]  # A + I over present nodes
    deg = [sum(r) for r in at]  # row degrees 2.5, 3, 4
    for i in range(3):
        for j in range(3):
            want = at[i][j] / math.sqrt(deg[i] * deg[j])
            assert got[i, j].item() == pytest.approx(want, rel=1e-6)
    assert torch.all(got[3] == 0) and torch.all(got[:, 3] == 0)
    # A GCN layer is relu(A_hat H W + b); padding rows are masked by the encoder.
    layer = GCNLayer(2, 3)
    h = torch.randn(4, 2)
    want = torch.relu(got @ (h @ layer.linear.weight.T) + layer.bias)
    assert torch.allclose(layer(h, got), want)


def test_uniform_adjacency():
    mask = torch.tensor([[True, True, True, False]])
    u = uniform_adjacency(mask)[0]
    assert u.tolist() == [
        [0.0, 1.0, 1.0, 0.0],
        [1.0, 0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0],
    ]
    n = normalized_adjacency(u, mask[0])
    assert torch.allclose(n[:3, :3], torch.full((3, 3), 1.0 / 3.0))


@pytest.mark.parametrize("graph", ["risk", "uniform", None])
def test_encoder_shapes_and_padding_invariance(graph):
    torch.manual_seed(0)
    enc = GraphEncoder(graph, max_agents=5, gcn_hidden=8, gcn_layers=2)
    f = torch.randn(3, 7, 5, 11)
    adj = torch.rand(3, 7, 5, 5)
    mask = torch.tensor([True, True, True, False, False]).expand(3, 7, 5)
    out = enc(f, adj, mask)
    assert out.shape == (3, 7, enc.out_features)
    # Padding content must not matter.
    f2, adj2 = f.clone(), adj.clone()
    f2[..., 3:, :] = 123.0
    adj2[..., 3:, :] = 5.0
    adj2[..., :, 3:] = 5.0
    assert torch.allclose(enc(f2, adj2, mask), out, atol=1e-6)
    if graph == "risk":  # the risk graph matters for the GCN over it only
        assert not torch.allclose(enc(f, adj * 0.1, mask), out)
    else:
        assert torch.allclose(enc(f, adj * 0.1, mask), out, atol=1e-6)


@pytest.mark.parametrize("network", [n for n, net in NETWORKS.items() if net.sac_label])
def test_actor_critic_loss_shapes(network):
    cfg = apply_overrides(
        TrainConfig(),
        dict(network=network, max_agents=4, num_envs=2, hidden_sizes=[16], gcn_hidden=8),
    )
    env = make_env(cfg.world, "train", cfg.algo.num_envs)
    actor = make_actor(cfg, env.action_spec_unbatched)
    critic = make_critic(cfg, env.action_spec_unbatched)
    with torch.no_grad():
        td = env.rollout(3, actor, break_when_any_done=False)
    assert td["action"].shape == (2, 3, 2) and td["action"].abs().max() <= 1.0
    assert critic(td.clone())["state_action_value"].shape == (2, 3, 1)
    loss, _ = make_loss(cfg, actor, critic)
    out = loss(td.reshape(-1))
    for key in ("loss_qvalue", "loss_actor", "loss_alpha"):
        assert out[key].shape == () and torch.isfinite(out[key])


def test_config_file_and_overrides(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('variant = "s_sac"\nnum_envs = 3\nhidden_sizes = [32, 16]\n')  # old name
    cfg = load_config(p, ["lr=1e-3", "save_buffer=true", "total_frames=1e4"])
    assert (cfg.net.network, cfg.algo.num_envs, cfg.algo.hidden_sizes) == ("mlp", 3, [32, 16])
    assert cfg.algo.lr == 1e-3 and cfg.algo.save_buffer is True and cfg.total_frames == 10_000
    with pytest.raises(KeyError):
        load_config(None, ["nope=1"])
    with pytest.raises(ValueError):
        load_config(None, ["network=foo"])


def test_a_retired_field_of_an_old_config_is_ignored_and_an_env_field_is_checked():
    """``env_backend`` (configs of shipped checkpoints have it; the Rust server is the only
    backend) is ignored; an env field is checked as the EnvSpec checks it, by name."""
    assert "env_backend" not in TrainConfig.from_dict({"env_backend": "remote"}).to_dict()
    assert load_config(None, ["env_backend=remote"]).world.server_endpoint == ""  # a local server
    with pytest.raises(ValueError, match="EnvSpec.vehicle_model"):
        load_config(None, ["vehicle_model=teleport"])
    with pytest.raises(ValueError, match="positon_sigma"):
        load_config(None, ['variations={"positon_sigma": 0.5}'])
