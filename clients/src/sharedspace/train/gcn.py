"""Graph encoders of the actor and the critics (paper Section IV.C).

A GCN layer is ``H' = sigma(D^-1/2 (A + I) D^-1/2 H W)`` (Kipf & Welling) on a batch of padded
graphs ``[B, M, M]``: padding rows and columns of ``A`` are zeroed, self-loops are added on present
nodes only and ``D`` is the row degree of ``A + I`` (``A[i][j]`` is the influence of ``j`` on ``i``,
so node ``i`` aggregates its row). Padding nodes are left out of the readout.

The graph an encoder convolves over (``GraphEncoder.graph``; the registered networks of
:mod:`sharedspace.train.networks` pick one, paper Table II):

- ``"risk"``: ``A`` = the env's risk graph ``psi (1 + lambda u)`` (``gcn_risk``, G-SAC-Cog);
- ``"uniform"``: 1 between every pair of distinct present nodes, 0 elsewhere (``gcn_uniform``,
  G-SAC-NoCog);
- ``None``: no graph, an MLP on the padded, masked node features flattened (``mlp``, S-SAC).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from sharedspace.names import FEATURE_SCALE

__all__ = [
    "FEATURE_SCALE",
    "FeatureNorm",
    "GCNLayer",
    "GraphEncoder",
    "normalized_adjacency",
    "present_nodes",
    "uniform_adjacency",
    "aggregate",
    "mlp",
    "readout",
]


def present_nodes(mask: torch.Tensor) -> int:
    """``1 +`` the index of the last node present in any observation of ``mask [*, M]`` (at
    least 1): the nodes after it are padding everywhere."""
    any_present = mask.reshape(-1, mask.shape[-1]).any(0)
    idx = torch.nonzero(any_present)
    return int(idx[-1, 0]) + 1 if idx.numel() else 1


def uniform_adjacency(mask: torch.Tensor) -> torch.Tensor:
    """``[..., M, M]``: 1 between distinct present nodes, 0 on the diagonal and for padding."""
    m = mask.to(torch.float32)
    eye = torch.eye(mask.shape[-1], dtype=m.dtype, device=m.device)
    return m.unsqueeze(-1) * m.unsqueeze(-2) * (1.0 - eye)


def normalized_adjacency(adjacency: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``D^-1/2 (A + I) D^-1/2`` with ``A`` masked to present nodes and self-loops on present
    nodes only; rows/columns of padding nodes are 0."""
    m = mask.to(adjacency.dtype)
    eye = torch.eye(adjacency.shape[-1], dtype=adjacency.dtype, device=adjacency.device)
    a = adjacency * m.unsqueeze(-1) * m.unsqueeze(-2) * (1.0 - eye) + eye * m.unsqueeze(-1)
    deg = a.sum(-1)
    inv_sqrt = torch.where(deg > 0, deg.clamp_min(1e-12).rsqrt(), torch.zeros_like(deg))
    return inv_sqrt.unsqueeze(-1) * a * inv_sqrt.unsqueeze(-2)


class GCNLayer(nn.Module):
    """One graph convolution ``sigma(A_hat H W)`` (``A_hat`` already normalised)."""

    def __init__(self, in_features: int, out_features: int, activation: bool = True):
        super().__init__()
        self.linear = nn.Linear(in_features, out_features, bias=False)  # W
        self.bias = nn.Parameter(torch.zeros(out_features))  # added after aggregation
        self.activation = nn.ReLU(inplace=True) if activation else nn.Identity()

    def forward(self, h: torch.Tensor, a_hat: torch.Tensor) -> torch.Tensor:
        return self.activation(aggregate(h, a_hat, self.linear.weight.T, self.bias))


def aggregate(
    h: torch.Tensor, a_hat: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor
) -> torch.Tensor:
    """``A_hat H W + b`` for ``h [*, M, F]``, ``a_hat [*, M, M]``, ``weight [F, O]``.

    The product is associative, so it aggregates first when that is the narrower side
    (``F < O``, e.g. the first layer's 11 features against 64) and the bias joins the last
    matmul: on the CPU a GCN layer is bound by memory traffic over ``[B, M, O]`` tensors, so
    every pass saved counts (docs/BENCHMARKS.md, "Learner")."""
    if h.shape[-1] < weight.shape[-1]:
        ah = a_hat @ h
        return torch.addmm(bias, ah.flatten(0, -2), weight).reshape(*ah.shape[:-1], -1)
    hw = h @ weight
    if hw.dim() == 3 and a_hat.dim() == 3:
        return torch.baddbmm(bias.expand_as(hw), a_hat, hw)
    return a_hat @ hw + bias


def mlp(
    sizes: Sequence[int],
    out: int | None = None,
    final_activation: bool = False,
    layer_norm: bool = False,
) -> nn.Sequential:
    """Linear + ReLU stack through ``sizes`` (then a plain ``Linear`` to ``out`` if given);
    with ``layer_norm`` a ``LayerNorm`` before each ReLU (RLPD's critics)."""
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:], strict=True):
        layers.append(nn.Linear(a, b))
        if layer_norm:
            layers.append(nn.LayerNorm(b))
        layers.append(nn.ReLU(inplace=True))  # a Linear's backward needs no output
    if out is not None:
        layers.append(nn.Linear(sizes[-1], out))
    elif not final_activation and layers:
        layers.pop()
        if layer_norm:
            layers.pop()
    return nn.Sequential(*layers)


class FeatureNorm(nn.Module):
    """Running mean and standard deviation of the scaled node features over present nodes, the
    ego node (node 0: it alone carries the goal features) apart from the others; applied as
    ``clamp((h - mean) / std, -clip, clip)`` on present nodes (padding stays 0).

    The statistics change only through :meth:`update` (the PPO loop calls it on each
    collected batch before its update), so a forward pass never moves them and a checkpoint's
    networks carry them in their state dicts. One instance is shared by an actor's and a
    critic's encoders."""

    def __init__(self, num_features: int = 11, clip: float = 10.0, eps: float = 1e-4):
        super().__init__()
        self.clip, self.eps = clip, eps
        self.register_buffer("mean", torch.zeros(2, num_features))
        self.register_buffer("var", torch.ones(2, num_features))
        self.register_buffer("count", torch.zeros(2))

    @torch.no_grad()
    def update(self, h: torch.Tensor, m: torch.Tensor) -> None:
        """Merges the batch ``h [*, M, F]`` (scaled features) with mask ``m [*, M, 1]`` into the
        running moments (Chan et al.'s parallel update)."""
        h, m = h.reshape(-1, *h.shape[-2:]), m.reshape(-1, m.shape[-2], 1)
        for role, (hs, ms) in enumerate(((h[:, :1], m[:, :1]), (h[:, 1:], m[:, 1:]))):
            n = ms.sum()
            if n < 1:
                continue
            mean = (hs * ms).sum((0, 1)) / n
            var = ((hs - mean) ** 2 * ms).sum((0, 1)) / n
            total = self.count[role] + n
            delta, seen = mean - self.mean[role], self.count[role]
            self.var[role] = (self.var[role] * seen + var * n + delta**2 * seen * n / total) / total
            self.mean[role] += delta * n / total
            self.count[role] = total

    def forward(self, h: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
        k = h.shape[-2]
        mean = torch.cat([self.mean[:1], self.mean[1:].expand(k - 1, -1)])
        std = torch.cat([self.var[:1], self.var[1:].expand(k - 1, -1)]).add(self.eps).sqrt()
        return ((h - mean) / std).clamp(-self.clip, self.clip) * m


class GraphEncoder(nn.Module):
    """Embeds one observation ``(features [*, M, F], adjacency [*, M, M], mask [*, M])`` into
    ``[*, out_features]``: a GCN over ``graph`` (``"risk"``: the env's adjacency, ``"uniform"``:
    every present pair), or with ``graph`` None an MLP over the flattened nodes."""

    #: The graphs a GCN encoder can convolve over.
    GRAPHS = ("risk", "uniform")

    def __init__(
        self,
        graph: str | None,
        max_agents: int,
        num_features: int = 11,
        gcn_hidden: int = 64,
        gcn_layers: int = 2,
        readout: str = "ego_mean",
        norm: FeatureNorm | None = None,
    ):
        super().__init__()
        self.graph = graph
        self.readout = readout
        self.norm = norm
        self.register_buffer("scale", torch.tensor(FEATURE_SCALE[:num_features]))
        if graph is None:
            self.layers = nn.ModuleList()
            self.flat = nn.Sequential(
                nn.Linear(max_agents * (num_features + 1), gcn_hidden * 2), nn.ReLU()
            )
            self.out_features = gcn_hidden * 2
        elif graph in self.GRAPHS:
            dims = [num_features] + [gcn_hidden] * gcn_layers
            self.layers = nn.ModuleList(
                GCNLayer(a, b) for a, b in zip(dims[:-1], dims[1:], strict=True)
            )
            self.out_features = gcn_hidden * (2 if readout == "ego_mean" else 1)
        else:
            raise ValueError(f"graph must be one of {self.GRAPHS} or None, not {graph!r}")

    def forward(self, features: torch.Tensor, adjacency: torch.Tensor, mask: torch.Tensor):
        return self.embed(*self.prepare(features, adjacency, mask))

    def update_norm(self, features: torch.Tensor, mask: torch.Tensor) -> None:
        """Folds a batch of observations into :attr:`norm`'s running moments (no-op without)."""
        if self.norm is not None:
            m = mask.to(features.dtype).unsqueeze(-1)
            self.norm.update(features / self.scale * m, m)

    def prepare(
        self, features: torch.Tensor, adjacency: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """The parameter-free part of the encoder: ``(h, a_hat, m)`` = scaled and masked node
        features ``[*, M, F]``, the normalised adjacency ``[*, M, M]`` (``None`` for the MLP)
        and the mask as ``[*, M, 1]`` floats. It depends on the graph only, so the actor and
        the critics of one update share it (:mod:`sharedspace.train.update`).

        Trailing nodes that are padding in every sample are dropped (``M`` becomes the last
        present node + 1): padding never reaches a present node, so the embedding is the same,
        and the paper's scenes fill 4 of the default 8 nodes."""
        k = present_nodes(mask)
        if k < mask.shape[-1]:
            features, adjacency, mask = features[..., :k, :], adjacency[..., :k, :k], mask[..., :k]
        m = mask.to(features.dtype).unsqueeze(-1)
        h = features / self.scale * m
        if self.norm is not None:
            h = self.norm(h, m)
        if self.graph is None:
            return h, None, m
        adj = adjacency if self.graph == "risk" else uniform_adjacency(mask)
        return h, normalized_adjacency(adj.to(h.dtype), mask), m

    def embed(self, h: torch.Tensor, a_hat: torch.Tensor | None, m: torch.Tensor) -> torch.Tensor:
        """``[*, out_features]`` from :meth:`prepare`'s output."""
        if self.graph is None:
            x = torch.cat([h, m], -1).flatten(-2)
            first = self.flat[0]  # dropped padding nodes are zero inputs: their weights go too
            return torch.relu(F.linear(x, first.weight[:, : x.shape[-1]], first.bias))
        # Padding nodes are not masked between layers: their columns of a_hat are 0, so they
        # never reach a present node, and the readout masks them.
        for layer in self.layers:
            h = layer(h, a_hat)
        return readout(h, m, self.readout)


def readout(h: torch.Tensor, m: torch.Tensor, kind: str) -> torch.Tensor:
    """Graph readout of node embeddings ``h [*, M, H]`` with mask ``m [*, M, 1]``: the ego node
    (node 0), and for ``ego_mean`` the mean over present nodes after it."""
    ego = h[..., 0, :]
    if kind == "ego":
        return ego
    mean = (m.transpose(-1, -2) @ h).squeeze(-2) / m.sum(-2).clamp_min(1.0)
    return torch.cat([ego, mean], -1)


class ActorNet(nn.Module):
    """Encoder + MLP to the Gaussian parameters ``[*, 2 * action_dim]`` (loc ++ raw scale)."""

    def __init__(self, encoder: GraphEncoder, hidden_sizes: Sequence[int], action_dim: int = 2):
        super().__init__()
        self.encoder = encoder
        self.head = mlp([encoder.out_features, *hidden_sizes], out=2 * action_dim)

    def forward(self, features, adjacency, mask):
        return self.head(self.encoder(features, adjacency, mask))


class QNet(nn.Module):
    """Encoder + MLP on (embedding ++ action) to ``Q [*, 1]``; ``layer_norm``: a LayerNorm
    after each hidden layer of the MLP (RLPD)."""

    def __init__(
        self,
        encoder: GraphEncoder,
        hidden_sizes: Sequence[int],
        action_dim: int = 2,
        layer_norm: bool = False,
    ):
        super().__init__()
        self.encoder = encoder
        self.head = mlp(
            [encoder.out_features + action_dim, *hidden_sizes], out=1, layer_norm=layer_norm
        )

    def forward(self, features, adjacency, mask, action):
        return self.head(torch.cat([self.encoder(features, adjacency, mask), action], -1))
