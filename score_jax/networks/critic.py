"""The centralised graph critic of SCORE (§4.2, Fig. 4) and its twin.

For ONE sample (the learner vmaps over the batch):

    e_o   = q_phi(o)                    state encoder     (the HVAE's when asrl=True, see below)
    e_a,i = mean of q_psi(z | o, a_i, c_i)  action encoder (the HVAE's when asrl=True)
    e_i   = p_w(e_o, e_a,i)             pairwise interaction MLP          -> params["p_w"]
    e^(m) = m masked GAT layers, Theta^(l) = MLP(s^t) (hypernet=True)    -> params["hyper"]
                                  or plain learned weights (hypernet=False) -> params["gat"]
    Q     = f_xi(Mean_{active i} e_i^(m))                                  -> params["f_xi"]

``GraphCritic.embeddings`` returns the agent embeddings e_i (after p_w) and e_i^(m) (after the
GAT) that Fig. 12 visualises; it runs the same modules as ``__call__``, so it reads the same
parameters and adds none.

With ``asrl=True, finetune_asrl=False`` (the paper's text) the HVAE parameters are an ARGUMENT
(wrapped in ``stop_gradient``), never part of the critic's parameters: they are frozen by
construction. Otherwise the critic owns an encoder of the same architecture (params["encoder"])
trained with it, and ignores ``hvae_params``: with ``finetune_asrl=True`` that encoder starts as
a copy of the ASRL HVAE's encoders (``agents.score.networks.init_state`` copies them in) and ``c``
are the ASRL codes; with ``asrl=False`` (the AL+HN ablation) it starts from scratch and ``c`` is
still an input (pass e.g. ``agents.score.networks.random_space_codes``). Transfer (§4.3)
fine-tunes ``FINETUNE_SUBTREES`` only (see ``finetune_mask``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from score_jax.networks.gat import (
    AGGREGATIONS,
    flatten_gat_weights,
    gat_num_params,
    gat_stack,
    init_gat_weights,
    unflatten_gat_weights,
)
from score_jax.networks.hvae import HVAE, HVAEConfig
from score_jax.networks.mlp import MLP
from score_jax.networks.stacked import stacked

FINETUNE_SUBTREES = ("p_w", "gat", "hyper", "f_xi")


@dataclasses.dataclass(frozen=True)
class CriticConfig:
    """Critic sizes and the ablation switches of the paper's Table (§5.4).

    Attributes:
      hidden: hidden width of p_w and f_xi.
      agent_dim: width of the agent embeddings e_i and of every GAT layer (the hypernetwork
        emits m (d^2 + 2d) weights per sample, so its cost grows with d squared; see the
        README's design notes for the measured choice).
      gat_layers: m, the number of GAT layers.
      aggregation: ``"attention"`` (GAT), ``"mean"`` or ``"sum"`` over active agents.
      hypernet: GAT weights from a hypernetwork of the state (True) or plain params (False).
      asrl: the critic's encoders and codes c_i come from the pre-trained HVAE (True) or are
        trained from scratch with the critic (False, the AL+HN ablation).
      finetune_asrl: with ``asrl``, the critic's encoders start as the HVAE's and train with
        the critic (True, the default: a frozen HVAE left the critic almost blind to actions,
        see the README's design notes), instead of staying frozen (False, the paper's text).
        The codes c_i stay ASRL's either way, so transfer embeds new sub-spaces as before.
        Without ``asrl`` the encoders always train (from scratch), so this switch has no effect
        there.
      hyper_hidden: hidden width of the hypernetwork MLP.
      layer_norm: a LayerNorm after every hidden layer of p_w, f_xi and the hypernetwork (a
        normalised critic, as SimBa / BRO / CrossQ).
      self_term: each GAT layer adds the receiver's own ``theta x_i`` inside its ELU
        (``x'_i = ELU(theta x_i + sum_j alpha_ij theta x_j)``, no extra weights). Off, the
        paper's update gives every agent of a state the same embedding (the attention on a
        complete graph is static, see ``networks.gat``); a departure from the paper, measured
        in ``docs/learning.md``.
    """

    hidden: int = 64
    agent_dim: int = 16
    gat_layers: int = 2
    aggregation: Literal["attention", "mean", "sum"] = "attention"
    hypernet: bool = True
    asrl: bool = True
    finetune_asrl: bool = True
    hyper_hidden: int = 32
    layer_norm: bool = False
    self_term: bool = False

    def __post_init__(self):
        if self.aggregation not in AGGREGATIONS:
            raise ValueError(
                f"unknown aggregation {self.aggregation!r}; choose one of {AGGREGATIONS}"
            )
        if self.gat_layers < 1:
            raise ValueError(f"gat_layers must be >= 1, got {self.gat_layers}")

    @property
    def frozen_encoders(self) -> bool:
        """True when the critic reads the frozen HVAE (its params an argument, not its own)."""
        return self.asrl and not self.finetune_asrl


@struct.dataclass
class AgentEmbeddings:
    """The critic's agent embeddings of one sample (add leading axes for batches).

    Attributes:
      p_w: ``[n, agent_dim]`` e_i = p_w(e_o, e_a,i), before any message passing.
      gat: ``[n, agent_dim]`` e_i^(m), the output of the last GAT layer (rows of inactive
        agents are exactly 0, see ``gat.gat_layer``).
    """

    p_w: jax.Array
    gat: jax.Array


class GATParams(nn.Module):
    """Plain learned GAT weights (``hypernet=False``), stored flat like the hypernet's output."""

    dims: tuple[int, ...]

    @nn.compact
    def __call__(self) -> jax.Array:
        init = lambda key, shape: flatten_gat_weights(init_gat_weights(key, self.dims))
        return self.param("weights", init, (gat_num_params(self.dims),))


class HyperNet(nn.Module):
    """Theta^(l) = MLP(s^t) (§4.2): ``obs [obs_size] -> list of m GATWeights``.

    The output layer's bias is initialised to a Glorot sample of the GAT weights and its
    kernel small, so at initialisation the generated weights are a well-scaled GAT plus a
    state-dependent perturbation (a plain lecun output would give theta entries of O(1),
    far too large for a d x d map).

    The output layer is one ``[hidden, gat_num_params]`` kernel (params ``out/kernel``,
    ``out/bias``, the flat layout of ``flatten_gat_weights``), but each GAT tensor is computed
    from its own column block of the kernel: slicing the small kernel instead of the
    ``[batch, gat_num_params]`` output saves a copy of every generated weight per sample.
    """

    dims: tuple[int, ...]
    hidden: int
    layer_norm: bool = False

    @nn.compact
    def __call__(self, state: jax.Array) -> list:
        size = gat_num_params(self.dims)
        h = nn.Dense(self.hidden, name="dense_0")(state)
        h = nn.relu(nn.LayerNorm(name="norm_0")(h) if self.layer_norm else h)
        bias_init = lambda key, shape, dtype=jnp.float32: flatten_gat_weights(
            init_gat_weights(key, self.dims)
        ).astype(dtype)
        kernel_init = nn.initializers.variance_scaling(0.01, "fan_in", "truncated_normal")
        kernel, bias = _HyperOut(self.hidden, size, kernel_init, bias_init, name="out")()
        # The flat layout cut into per-tensor blocks: kernel blocks [hidden, *shape],
        # bias blocks [*shape].
        kernels, biases = (
            unflatten_gat_weights(kernel, self.dims),
            unflatten_gat_weights(bias, self.dims),
        )
        return jax.tree.map(lambda k, b: jnp.tensordot(h, k, axes=1) + b, kernels, biases)


class _HyperOut(nn.Module):
    """The hypernetwork's output layer parameters, stored like ``nn.Dense(size)``'s."""

    features_in: int
    size: int
    kernel_init: Any
    bias_init: Any

    @nn.compact
    def __call__(self) -> tuple[jax.Array, jax.Array]:
        return self.param("kernel", self.kernel_init, (self.features_in, self.size)), self.param(
            "bias", self.bias_init, (self.size,)
        )


def _frozen_hvae(hvae_config: HVAEConfig, obs_size: int, action_width: int) -> HVAE:
    # parent=None: an unbound module, so calling .apply inside the critic does not adopt it
    # as a submodule (its params stay out of the critic's tree).
    return HVAE(hvae_config, obs_size, action_width, parent=None)


class GraphCritic(nn.Module):
    """Q(o, {a_i}) for ONE sample over n agents (padded / failed ones masked)."""

    config: CriticConfig
    hvae_config: HVAEConfig
    obs_size: int
    action_width: int

    def _gat_dims(self) -> tuple[int, ...]:
        return (self.config.agent_dim,) * (self.config.gat_layers + 1)

    @nn.compact
    def __call__(
        self,
        obs: jax.Array,
        actions: jax.Array,
        dim_mask: jax.Array,
        c: jax.Array,
        mask: jax.Array,
        hvae_params: Any = None,
        return_attention: bool = False,
        return_embeddings: bool = False,
    ):
        """Args:
          obs: ``[obs_size]`` observation (shared by all sub-spaces).
          actions: ``[n, width]`` normalised actions, padded columns zero.
          dim_mask: ``[n, width]`` bool real columns.
          c: ``[n, c_dim]`` sub-space embeddings.
          mask: ``[n]`` bool, active agents (failed / dropped / padded agents False).
          hvae_params: the HVAE ``"params"`` (required with frozen encoders, else ignored).
          return_attention: also return the attention weights.
          return_embeddings: also return the agent embeddings (``AgentEmbeddings``).

        Returns:
          ``q []``; with ``return_attention`` and/or ``return_embeddings`` the tuple
          ``(q [], alpha [m, n, n], AgentEmbeddings)`` without the parts not asked for.
        """
        cfg = self.config
        if cfg.frozen_encoders:
            if hvae_params is None:
                raise ValueError(
                    "CriticConfig.asrl=True needs the trained HVAE params (hvae_params); got None"
                )
            frozen = jax.lax.stop_gradient(hvae_params)
            hvae = _frozen_hvae(self.hvae_config, self.obs_size, self.action_width)
            e_o = hvae.apply({"params": frozen}, obs, method=HVAE.encode_obs)
            e_a = hvae.apply(
                {"params": frozen}, obs, actions, dim_mask, c, method=HVAE.encode_action
            )[0]
        else:
            encoder = HVAE(self.hvae_config, self.obs_size, self.action_width, name="encoder")
            e_o = encoder.encode_obs(obs)
            e_a = encoder.encode_action(obs, actions, dim_mask, c)[0]
        # e_i = p_w(e_o, e_a,i) on the concatenation [e_o, e_a,i], e_o's product computed once
        # for all agents
        e = MLP((cfg.hidden,), cfg.agent_dim, layer_norm=cfg.layer_norm, name="p_w")((e_o, e_a))

        dims = self._gat_dims()
        if cfg.hypernet:
            weights = HyperNet(dims, cfg.hyper_hidden, cfg.layer_norm, name="hyper")(obs)
        else:
            weights = unflatten_gat_weights(GATParams(dims, name="gat")(), dims)
        x, alpha = gat_stack(weights, e, mask, cfg.aggregation, cfg.self_term)

        w = jnp.asarray(mask, jnp.float32)[:, None]
        pooled = jnp.sum(x * w, 0) / jnp.maximum(jnp.sum(w), 1.0)  # Mean over active agents
        q = MLP((cfg.hidden,), 1, layer_norm=cfg.layer_norm, name="f_xi")(pooled)[0]
        extra = (alpha,) if return_attention else ()
        extra += (AgentEmbeddings(e, x),) if return_embeddings else ()
        return (q, *extra) if extra else q

    def attention_weights(self, obs, actions, dim_mask, c, mask, hvae_params=None) -> jax.Array:
        """``alpha [m, n, n]`` of every GAT layer (rows: receiver i, columns: sender j)."""
        return self(obs, actions, dim_mask, c, mask, hvae_params, return_attention=True)[1]

    def embeddings(self, obs, actions, dim_mask, c, mask, hvae_params=None) -> AgentEmbeddings:
        """The agent embeddings after p_w and after the GAT (``[n, agent_dim]`` each)."""
        return self(obs, actions, dim_mask, c, mask, hvae_params, return_embeddings=True)[1]


class TwinCritic(nn.Module):
    """Two independent GraphCritics (params stacked on a leading axis of 2): ``-> q [2]``.

    Parameters live under ``params["critics"]`` with the GraphCritic's subtrees inside.
    """

    config: CriticConfig
    hvae_config: HVAEConfig
    obs_size: int
    action_width: int

    @nn.compact
    def __call__(self, obs, actions, dim_mask, c, mask, hvae_params=None):
        return stacked(GraphCritic, 2)(
            self.config, self.hvae_config, self.obs_size, self.action_width, name="critics"
        )(obs, actions, dim_mask, c, mask, hvae_params)


def finetune_mask(params: Any, encoder: bool = False) -> Any:
    """Pytree of bools over critic params (GraphCritic or TwinCritic): True on the subtrees
    transfer fine-tunes (``p_w``, ``gat`` / ``hyper``, ``f_xi``, §4.3), False elsewhere
    (the critic's own encoder when it has one, unless ``encoder``). Use with
    ``optax.masked`` or ``optax.multi_transform``."""
    subtrees = FINETUNE_SUBTREES + (("encoder",) if encoder else ())

    def mark(path, _):
        names = [getattr(p, "key", getattr(p, "name", None)) for p in path]
        return any(name in subtrees for name in names)

    return jax.tree_util.tree_map_with_path(mark, params)
