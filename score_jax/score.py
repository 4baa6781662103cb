"""SCORE assembled (§4, Alg. 1): ASRL-pretrained HVAE, hypernetwork GAT twin critic,
decentralised per-sub-space SAC actors, DropNode, one jitted update.

The ablations of Table 2 are switches of ``CriticConfig`` (aggregation, hypernet, asrl), not
separate code. With ``asrl=False`` the encoders are trained from scratch inside the critic
and the sub-space codes c_i are free parameters learned with the critic.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from score_jax import asrl
from score_jax.networks.actor import ActorConfig, Actors, actor_policy
from score_jax.networks.critic import CriticConfig, TwinCritic
from score_jax.networks.hvae import HVAE, HVAEConfig, init_hvae
from score_jax.sac import AgentConsts, SACHyper, SACState, make_sac_update, target_entropy
from score_jax.spaces import CompositeSpace, pad_width


@dataclasses.dataclass(frozen=True)
class ScoreConfig:
    """SCORE hyperparameters (network sizes are static; the SAC scalars are fed as arrays)."""

    hvae: HVAEConfig = HVAEConfig()
    critic: CriticConfig = CriticConfig()
    actor: ActorConfig = ActorConfig()
    asrl_k: int = 16
    """Random fixings of the other sub-spaces per sub-space (§4.1)."""
    asrl_j: int = 8
    """Random sub-actions per fixing (§4.1)."""
    asrl_steps: int = 1500
    """HVAE training steps."""
    action_width: int = 0
    """Padded action width; 0 = the environment's full max_dim (so transfer can add sub-spaces)."""
    actor_lr: float = 1e-4
    """Adam step size of the actors (a tenth of the critic's: Adam moves the actors by about
    this much per update even when the critic's action gradient is mostly noise)."""
    critic_lr: float = 1e-3
    """Adam step size of the critics (and of c_i when ASRL is off)."""
    alpha_lr: float = 3e-4
    """Adam step size of log alpha (automatic entropy tuning)."""
    init_alpha: float = 0.1
    """Initial entropy temperature alpha."""
    gamma: float = 0.99
    """Discount factor."""
    tau: float = 0.005
    """Polyak rate of the target critics (Alg. 1 line 15: rho = 1 - tau)."""
    dropnode_prob: float = 0.1
    """Probability that an agent is masked in the critic during an update (DropNode, §4.2)."""
    reward_scale: float = 0.0
    """Rewards are multiplied by this in the critic target; 0 = the environment's suggestion
    (``env.reward_scale``: 0.05 for the greenhouse's cumulative reward, else 1)."""
    grad_clip: float = 10.0
    """Global-norm gradient clipping of actors and critics."""
    discrete_entropy_scale: float = 0.1
    """Entropy target of a discrete dim as a fraction of a uniform choice's, ``scale * log(n_choices)``.
    Small enough that the deterministic (argmax) action is the choice the stochastic policy
    mostly plays, so evaluation sees what training explored."""
    continuous_entropy_target: float = -1.0
    """Entropy target per continuous dim (SAC's usual -1 per dim)."""


@struct.dataclass
class CriticVars:
    """Trainable critic variables: the twin network, and c_i when ASRL is off (else None)."""

    net: Any
    c: Any


@struct.dataclass
class FrozenInputs:
    """The frozen ASRL outputs the critic reads (None fields when ASRL is off)."""

    hvae_params: Any
    c: Any


@dataclasses.dataclass(frozen=True)
class ScoreNetworks:
    """Static structure of SCORE for one (observation size, agent count, width)."""

    config: ScoreConfig
    obs_size: int
    n_agents: int
    width: int
    max_choices: int
    discrete_width: int = 0

    @property
    def actors(self) -> Actors:
        return Actors(self.config.actor, self.n_agents, self.width, self.max_choices, self.discrete_width)

    @property
    def critic(self) -> TwinCritic:
        return TwinCritic(self.config.critic, self.config.hvae, self.obs_size, self.width)

    @property
    def hvae(self) -> HVAE:
        return HVAE(self.config.hvae, self.obs_size, self.width)

    def policy_fn(self, actor_params, consts: AgentConsts, obs, key, deterministic=False):
        """``obs [B, obs] -> (action [B, n, w], log_prob [B, n])`` (Alg. 1 line 2)."""
        return actor_policy(self.actors, actor_params, consts, obs, key, deterministic)

    def q_fn(self, critic: CriticVars, consts: AgentConsts, obs, action, mask):
        """``[B, obs], [B, n, w], [B, n] -> [B, 2]`` twin Q-values (§4.2)."""
        frozen: FrozenInputs = consts.critic_inputs
        c = frozen.c if self.config.critic.asrl else critic.c
        apply = lambda o, a, m: self.critic.apply({"params": critic.net}, o, a, consts.dim_mask, c, m & consts.valid, frozen.hvae_params)
        return jax.vmap(apply)(obs, action, mask)


def agent_consts(space: CompositeSpace, agent_index, width: int, frozen: FrozenInputs, entropy: tuple[float, float] = (0.1, -1.0)) -> AgentConsts:
    """Per-agent arrays for the sub-spaces ``agent_index`` of ``space``, padded to ``width``."""
    idx = np.asarray(agent_index)
    dim_mask = pad_width(jnp.asarray(space.dim_mask[idx]), width, False)
    n_choices = pad_width(jnp.asarray(space.n_choices[idx]), width, 0)
    default = pad_width(jnp.asarray(space.default_action())[idx], width, 0.0)
    return AgentConsts(dim_mask, n_choices, jnp.ones(len(idx), bool), target_entropy(dim_mask, n_choices, *entropy), frozen, default)


def make_optimizers(cfg: ScoreConfig):
    clip = optax.clip_by_global_norm(cfg.grad_clip)
    return (
        optax.chain(clip, optax.adam(cfg.actor_lr)),
        optax.chain(clip, optax.adam(cfg.critic_lr)),
        optax.adam(cfg.alpha_lr),
    )


def init_state(nets: ScoreNetworks, key: jax.Array, consts: AgentConsts, optimizers=None) -> SACState:
    """Fresh actor/critic parameters, targets, optimiser states and log alpha."""
    cfg = nets.config
    key_actor, key_critic, key_c = jax.random.split(key, 3)
    obs = jnp.zeros(nets.obs_size)
    actions = jnp.zeros((nets.n_agents, nets.width))
    actor = nets.actors.init(key_actor, obs)["params"]
    free_c = None if cfg.critic.asrl else asrl.random_space_codes(key_c, nets.n_agents, cfg.hvae.space_embed_dim)
    c = consts.critic_inputs.c if cfg.critic.asrl else free_c
    net = nets.critic.init(key_critic, obs, actions, consts.dim_mask, c, consts.valid, consts.critic_inputs.hvae_params)["params"]
    critic = CriticVars(net, free_c)
    actor_opt, critic_opt, alpha_opt = optimizers or make_optimizers(cfg)
    log_alpha = jnp.full((nets.n_agents,), jnp.log(cfg.init_alpha), jnp.float32)  # one temperature per agent
    return SACState(
        actor=actor, critic=critic, target_critic=critic, log_alpha=log_alpha,
        actor_opt=actor_opt.init(actor), critic_opt=critic_opt.init(critic), alpha_opt=alpha_opt.init(log_alpha), consts=consts,
    )


def hyper(cfg: ScoreConfig, env) -> SACHyper:
    f = lambda x: jnp.asarray(x, jnp.float32)
    reward_scale = cfg.reward_scale or getattr(env, "reward_scale", 1.0)
    return SACHyper(gamma=f(cfg.gamma), tau=f(cfg.tau), dropnode_prob=f(cfg.dropnode_prob), reward_scale=f(reward_scale))


def make_update(nets: ScoreNetworks, optimizers=None):
    """The one-jit SAC update of Alg. 1 lines 11-15 for these networks."""
    return make_sac_update(nets.policy_fn, nets.q_fn, *(optimizers or make_optimizers(nets.config)))


def pretrain(env, agent_index, cfg: ScoreConfig, width: int, key: jax.Array, log=print, fixed_default=None) -> FrozenInputs:
    """The ASRL stage (§4.1): HVAE trained on random-policy observation sets of the agents' sub-spaces."""
    if not cfg.critic.asrl:
        return FrozenInputs(None, None)

    def progress(step, m):
        log(f"  ASRL step {step}/{cfg.asrl_steps}: ELBO {float(m.elbo):.2f} (recon {float(m.recon):.2f}, pred {float(m.pred):.2f}, KL_z {float(m.kl_z):.2f})")

    result = asrl.train_hvae(
        env, key, cfg.hvae, agents=[int(i) for i in agent_index], k=cfg.asrl_k, j=cfg.asrl_j, steps=cfg.asrl_steps,
        action_width=width, fixed_default=fixed_default, progress=progress, log_every=max(cfg.asrl_steps // 4, 1),
    )
    return FrozenInputs(result.params, result.c)


def frozen_template(env, agent_index, cfg: ScoreConfig, width: int) -> FrozenInputs:
    """Shapes of the ASRL outputs without running ASRL (filled in by a checkpoint restore).

    Traced with ``jax.eval_shape`` through the real data collection and HVAE init, so it
    always matches what ``pretrain`` produces; nothing is computed.
    """
    if not cfg.critic.asrl:
        return FrozenInputs(None, None)
    model = HVAE(cfg.hvae, env.observation_size, width)
    agents = [int(i) for i in agent_index]

    def build(key):
        sets = asrl.collect_observation_sets(env, key, agents, 1, 2, cfg.hvae.predict_steps, width, warmup_steps=1)
        return init_hvae(model, key, sets)

    shapes = jax.eval_shape(build, jax.random.PRNGKey(0))
    params = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
    return FrozenInputs(params, jnp.zeros((len(agents), cfg.hvae.space_embed_dim)))
