"""The networks a learner can put between the observation and its heads, each registered once.

A network is an *encoder*: a ``torch.nn.Module`` that embeds one observation
``(features [*, M, F], adjacency [*, M, M], mask [*, M])`` into ``[*, out_features]``. Every
algorithm builds its actor and critics as this encoder plus its own MLP heads, so a network
registered here serves every algorithm that builds on encoders (PPO; SAC's fused update takes
the built-in graph encoders, :attr:`Network.fused_sac`).

The paper's three (Section V.B, Table II):

- ``gcn_risk``: a GCN over the env's risk graph ``A = psi (1 + lambda u)``; the paper's SAC
  row G-SAC-Cog (old names ``g_sac_cog``, ``gcn_cog``);
- ``gcn_uniform``: the same GCN over the uniform graph of present nodes; G-SAC-NoCog (old
  names ``g_sac_nocog``, ``gcn_nocog``);
- ``mlp``: no graph, an MLP over the flattened nodes; S-SAC (old name ``s_sac``).

Adding one (docs/ARCHITECTURE.md, "Adding a network")::

    from sharedspace.train.networks import Network, register_network

    register_network(Network("my_net", "MyNet", lambda cfg, norm: MyEncoder(cfg.max_agents)))

after which ``--set network=my_net`` trains it. An encoder may hold a
:class:`~sharedspace.train.gcn.FeatureNorm` as ``norm`` (PPO's running feature normalisation,
updated through ``update_norm(features, mask)`` when the encoder has that method).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from sharedspace.cli import UserError, did_you_mean
from sharedspace.train.registry import ALGORITHMS

if TYPE_CHECKING:  # torch is imported where a network is built, not where one is named
    from torch import nn

    from sharedspace.train.gcn import FeatureNorm, GraphEncoder

__all__ = [
    "NETWORKS",
    "NETWORK_KEYS",
    "Network",
    "NetworkConfig",
    "NetworkConfigError",
    "UnknownNetwork",
    "canonical_network",
    "get_network",
    "network_label",
    "register_network",
]


class NetworkConfigError(UserError):
    """A network option with a wrong value."""


class UnknownNetwork(NetworkConfigError):
    """A network name that no registered network has."""


@dataclass(frozen=True)
class NetworkConfig:
    """A run's network part: the network and its sizes (``--set`` keys :data:`NETWORK_KEYS`),
    with the world's ``max_agents`` and the run's ``device`` that an encoder is built with
    (:class:`~sharedspace.train.config.TrainConfig` fills those two in; the multi-car learners
    give one car's)."""

    network: str = "gcn_risk"  # a registered network: gcn_risk (GCN on the risk graph) |
    #                            gcn_uniform (GCN, uniform graph) | mlp (no graph); "" = each
    #                            car's nodes flattened into its MLP (several cars)
    gcn_hidden: int = 64  # width of each GCN layer's output
    gcn_layers: int = 2  # number of GCN layers (ignored by mlp)
    readout: str = "ego_mean"  # graph readout: "ego" (node 0) | "ego_mean" (node 0 ++ mean)
    max_agents: int = 8  # M, graph nodes per observation: the world's
    device: str = "cpu"  # torch device the encoder is put on: the run's

    def __post_init__(self):
        if self.readout not in ("ego", "ego_mean"):
            raise NetworkConfigError(f"readout must be ego or ego_mean, not {self.readout!r}")


#: The ``--set`` keys of a run's network part (``max_agents`` is the world's, ``device`` the
#: run's).
NETWORK_KEYS = ("network", "gcn_hidden", "gcn_layers", "readout")


@dataclass(frozen=True)
class Network:
    """One registered network."""

    name: str  # what ``--set network=...`` and a checkpoint call it
    label: str  # the row label of any algorithm's learner with it (e.g. "GCN-Cog")
    #: ``(cfg, norm) -> encoder``: ``cfg`` is a :class:`NetworkConfig` (``max_agents``,
    #: ``gcn_hidden``, ``gcn_layers``, ``readout``); ``norm`` is the feature normalisation to
    #: hold, or None
    make_encoder: Callable[[NetworkConfig, FeatureNorm | None], nn.Module]
    aliases: tuple[str, ...] = ()  # older names, accepted wherever a name is
    sac_label: str = ""  # the paper's label of its SAC row (S-SAC, G-SAC-NoCog, G-SAC-Cog)
    fused_sac: bool = False  # SAC's fused update (train/update.py) knows this encoder
    doc: str = ""  # one line: what it is


#: Every registered network by name.
NETWORKS: dict[str, Network] = {}
_ALIASES: dict[str, str] = {}


def register_network(network: Network) -> Network:
    """Registers ``network`` (its name and aliases); a name taken by another is refused."""
    for name in (network.name, *network.aliases):
        owner = _ALIASES.get(name)
        if owner is not None and owner != network.name:
            raise ValueError(f"network name {name!r} is taken by network {owner!r}")
    NETWORKS[network.name] = network
    for name in (network.name, *network.aliases):
        _ALIASES[name] = network.name
    return network


def canonical_network(name: str) -> str:
    """The registered name of ``name`` (an alias resolves); :class:`UnknownNetwork` naming the
    registered ones otherwise."""
    if name not in _ALIASES:
        known = ", ".join(
            f"{n} ({', '.join(e.aliases)})" if e.aliases else n for n, e in NETWORKS.items()
        )
        raise UnknownNetwork(
            f"network must be one of {known}; not {name!r}" + did_you_mean(name, _ALIASES)
        )
    return _ALIASES[name]


def get_network(name: str) -> Network:
    """The registered network of ``name`` (or of an alias of it)."""
    return NETWORKS[canonical_network(name)]


def network_label(name: str, algorithm: str = "") -> str:
    """A row label: the paper's label (S-SAC, ...) for an algorithm whose rows take them (SAC's,
    the registry's ``paper_labels``), else the network's; a name no network has is returned as
    given."""
    try:
        net = get_network(name)
    except UnknownNetwork:
        return name
    paper = algorithm in ALGORITHMS and ALGORITHMS[algorithm].paper_labels
    return net.sac_label if paper and net.sac_label else net.label


def _graph_encoder(graph: str | None) -> Callable[[NetworkConfig, FeatureNorm | None], nn.Module]:
    def make(cfg: NetworkConfig, norm: FeatureNorm | None) -> GraphEncoder:
        from sharedspace.train.gcn import GraphEncoder

        return GraphEncoder(
            graph,
            cfg.max_agents,
            gcn_hidden=cfg.gcn_hidden,
            gcn_layers=cfg.gcn_layers,
            readout=cfg.readout,
            norm=norm,
        )

    return make


#: The paper's three (Section V.B): name, label, graph, old names, the paper's SAC label, doc.
for _name, _label, _graph, _aliases, _paper, _doc in (
    ("gcn_risk", "GCN-Cog", "risk", ("g_sac_cog", "gcn_cog"), "G-SAC-Cog", "GCN, risk graph"),
    ("gcn_uniform", "GCN-NoCog", "uniform", ("g_sac_nocog", "gcn_nocog"), "G-SAC-NoCog", "GCN"),
    ("mlp", "MLP", None, ("s_sac",), "S-SAC", "no graph: the nodes flattened into an MLP"),
):
    register_network(
        Network(
            _name,
            _label,
            _graph_encoder(_graph),
            aliases=_aliases,
            sac_label=_paper,
            fused_sac=True,
            doc=_doc,
        )
    )
