"""H-PPO (Fan et al. 2019, "Hybrid actor-critic RL in parameterized action space"; §5.1).

Parallel sub-actors, one per sub-action space, over a shared state encoder, and one shared
state-value critic. A continuous sub-space's head outputs a tanh-normal, a discrete one's
(the greenhouse's lamp / irrigation hours) a categorical per dim; the joint policy is their
product (``CompositeDistribution``), so its log-prob is the sum of the heads' log-probs over
real dims only.

Training reuses brax's PPO loop unchanged (``agents.brax.agents.build`` with this network factory):
brax's PPO takes any ``ParametricDistribution``. One difference from Fan et al.: brax clips
the ratio of the JOINT policy, where H-PPO clips each sub-actor's own ratio; a per-head clip
would need a second PPO loss, and the joint clip is the standard PPO objective of the same
product policy.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from brax.training import networks as brax_networks
from brax.training import types as brax_types
from brax.training.agents.ppo.networks import PPONetworks

from score_jax.agents.base import Algorithm, BuildContext
from score_jax.agents.brax import agents as brax_agents
from score_jax.agents.brax.composite_dist import CompositeDistribution
from score_jax.agents.brax.config import SingleAgentConfig


class SubActorHead(nn.Module):
    """One sub-space's head: ``features [..., h] -> distribution parameters [..., out]``."""

    hidden: int
    out: int

    @nn.compact
    def __call__(self, h):
        return nn.Dense(self.out, name="out")(nn.swish(nn.Dense(self.hidden, name="hidden")(h)))


class HPPOPolicy(nn.Module):
    """``obs [..., obs] -> [..., P]``: shared trunk, then parallel heads ``head_<i>`` (sub-space
    i)."""

    head_sizes: tuple[int, ...]
    trunk: tuple[int, ...]
    head_hidden: int

    @nn.compact
    def __call__(self, obs):
        h = obs
        for i, width in enumerate(self.trunk):
            h = nn.swish(nn.Dense(width, name=f"trunk_{i}")(h))
        return jnp.concatenate(
            [
                SubActorHead(self.head_hidden, size, name=f"head_{i}")(h)
                for i, size in enumerate(self.head_sizes)
            ],
            axis=-1,
        )


def make_hppo_networks(space, trunk: Sequence[int], head_hidden: int):
    """A brax PPO ``network_factory`` for ``space``:
    ``(obs_size, action_size, preprocess_observations_fn) -> PPONetworks``."""

    def factory(
        observation_size,
        action_size: int,
        preprocess_observations_fn=brax_types.identity_observation_preprocessor,
    ) -> PPONetworks:
        dist = CompositeDistribution(space)
        if action_size != dist.total_dim:
            raise ValueError(
                f"H-PPO networks for a {dist.total_dim}-dim composite action "
                f"got action_size={action_size}"
            )
        obs_dim = int(
            observation_size
            if isinstance(observation_size, (int, np.integer))
            else observation_size[-1]
        )
        module = HPPOPolicy(dist.head_sizes, tuple(trunk), head_hidden)
        policy = brax_networks.FeedForwardNetwork(
            init=lambda key: module.init(key, jnp.zeros((1, obs_dim))),
            apply=lambda processor_params, params, obs: module.apply(
                params, preprocess_observations_fn(obs, processor_params)
            ),
        )
        value = brax_networks.make_value_network(
            obs_dim,
            preprocess_observations_fn=preprocess_observations_fn,
            hidden_layer_sizes=tuple(trunk),
        )
        return PPONetworks(
            policy_network=policy, value_network=value, parametric_action_distribution=dist
        )

    return factory


def hppo_head_mask(space, unseen: np.ndarray, params) -> dict:
    """Unseen heads of the H-PPO policy: every parameter of ``head_<i>`` for unseen sub-space i."""
    return {
        "params": {
            name: jax.tree.map(
                lambda _, name=name: np.asarray(
                    name.startswith("head_") and bool(unseen[int(name.split("_")[1])])
                ),
                sub,
            )
            for name, sub in params["params"].items()
        }
    }


def hppo_start(space, prior: np.ndarray, sc: SingleAgentConfig):
    """``start(params) -> params``: the initial H-PPO policy parameters with the default prior:
    every head's output kernel scaled by ``sc.head_init_scale`` and its bias offset by the
    head's slice of ``CompositeDistribution.prior_bias`` (sub-spaces marked in ``prior [n]``:
    tanh-normal mean at the default, logit bonus ``sc.prior_logit`` on the default choice; the
    others start mid-range with uniform logits)."""
    dist = CompositeDistribution(space)
    bias = dist.prior_bias(prior, sc.prior_logit)
    bounds = np.cumsum((0,) + dist.head_sizes)

    def start(params):
        layers = dict(params["params"])
        for i in range(space.n):
            head = layers[f"head_{i}"]
            out = {
                "kernel": head["out"]["kernel"] * sc.head_init_scale,
                "bias": head["out"]["bias"] + bias[bounds[i] : bounds[i + 1]],
            }
            layers[f"head_{i}"] = {**head, "out": out}
        return {**params, "params": layers}

    return start


def make_hppo(sc: SingleAgentConfig, ctx: BuildContext) -> Algorithm:
    """H-PPO on brax's PPO loop."""
    factory = make_hppo_networks(ctx.space, sc.hidden, sc.head_hidden)
    return brax_agents.build(sc, ctx, "hppo", "ppo", factory, hppo_head_mask, hppo_start)
