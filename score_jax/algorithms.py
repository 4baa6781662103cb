"""Algorithm registry: ``--algo NAME`` -> an ``Algorithm`` the shared trainer, evaluation,
robustness sweep and transfer all drive the same way."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax
import numpy as np

from score_jax import score
from score_jax.evaluation import ActFn, EvalResult, make_evaluator
from score_jax.trainer import OffPolicyAlgorithm


@dataclasses.dataclass(frozen=True)
class Algorithm:
    """An off-policy algorithm plus how to read its deterministic policy out of a state.

    ``policy(agent_state) -> act_fn(env_state_batch, key) -> [E, n_agents, width]``.
    ``grow(source_run, template_agent_state, plan, key) -> agent_state`` grows a trained run's
    agent axis by unseen sub-spaces (§4.3, ``transfer.py``); None for an algorithm whose
    networks are tied to a fixed set of sub-spaces.
    """

    name: str
    off_policy: OffPolicyAlgorithm
    policy: Callable[[Any], ActFn]
    networks: Any = None
    grow: Callable[..., Any] | None = None
    train_external: Callable[..., Any] | None = None
    """Set by algorithms that run their own training loop (brax SAC / PPO, H-PPO):
    ``train_external(run, total_steps, report, initial_agent) -> agent_state``; then
    ``off_policy`` only supplies ``init`` (the saved state's template), ``act``, ``n_agents``
    and ``width``, and ``score_jax.external_loop`` drives the run."""

    def evaluate(self, run, state, n_episodes: int, n_failed=0, mode=0, key=None) -> EvalResult:
        """Deterministic-policy episodes of ``state.agent`` (one compiled evaluator per run and
        episode count, reused for every later call)."""
        key = jax.random.PRNGKey(run.config.seed + 10_000) if key is None else key
        cache = self.__dict__.setdefault("_evaluators", {})  # frozen dataclass: a per-instance cache
        slot = (id(run.env), tuple(int(i) for i in run.agent_index), int(n_episodes))
        if slot not in cache:
            cache[slot] = make_evaluator(run.env, self.policy, run.agent_index, n_episodes)
        return cache[slot](state.agent, key, n_failed, mode)


def action_width(cfg, env) -> int:
    width = cfg.score.action_width or env.space.max_dim
    if width < env.space.max_dim:
        raise ValueError(f"action_width={width} is smaller than the environment's max_dim={env.space.max_dim}")
    return width


def discrete_width(space) -> int:
    """Most dims of any discrete sub-space of the (full) environment space."""
    return max([s.dim for s in space.subspaces if s.kind == "discrete"] + [1])


def make_score(cfg, env, agent_index, key, pretrain: bool = True, log=print) -> Algorithm:
    sc = cfg.score
    width = action_width(cfg, env)
    nets = score.ScoreNetworks(sc, env.observation_size, len(agent_index), width, env.space.max_choices, discrete_width(env.space))
    fixed = np.ones(env.space.n, bool)
    fixed[np.asarray(agent_index)] = False
    key_asrl, _ = jax.random.split(key)
    if pretrain:
        log(f"ASRL: training the HVAE on observation sets of {len(agent_index)} sub-spaces ...")
        frozen = score.pretrain(env, agent_index, sc, width, key_asrl, log=log, fixed_default=fixed)
    else:
        frozen = score.frozen_template(env, agent_index, sc, width)
    consts = score.agent_consts(env.space, agent_index, width, frozen, (sc.discrete_entropy_scale, sc.continuous_entropy_target))
    optimizers = score.make_optimizers(sc)
    if cfg.transfer_new:  # a fine-tuning run grown from a subset run (§4.3)
        from score_jax import transfer

        new = set(cfg.transfer_new.split(","))
        trainable = np.asarray([cfg.finetune_old_actors or env.space.names[i] in new for i in agent_index])
        optimizers = transfer.transfer_optimizers(sc, trainable, sc.critic.asrl)
    update = score.make_update(nets, optimizers)

    def act(state, obs, key, deterministic):
        return nets.policy_fn(state.actor, state.consts, obs, key, deterministic)[0]

    off = OffPolicyAlgorithm("score", lambda k: score.init_state(nets, k, consts, optimizers), act, update, score.hyper(sc, env), len(agent_index), width)
    policy = lambda agent: (lambda env_state, k: act(agent, env_state.obs, k, True))
    return Algorithm("score", off, policy, nets, _grow_score)


def _grow_score(src_run, template, plan, key):
    """SCORE transfer (§4.3): embed the new sub-spaces with the frozen HVAE, then grow."""
    from score_jax import transfer

    new_c = transfer.embed_new(src_run, src_run.env, plan, key)
    return transfer.grow_agent(src_run.state.agent, template, plan, new_c, key)


# name -> builder, or "module:function" of a builder imported on first use (so importing the
# registry never imports every baseline). A builder has the signature of ``make_score``.
REGISTRY: dict[str, Callable[..., Algorithm] | str] = {
    "score": make_score,
    "sac": "score_jax.baselines.brax_agents:make_sac",
    "ppo": "score_jax.baselines.brax_agents:make_ppo",
    "hppo": "score_jax.baselines.hppo:make_hppo",
    "isac": "score_jax.baselines.isac:make_isac",
    "maddpg": "score_jax.baselines.maddpg:make_maddpg",
    "maac": "score_jax.baselines.maac:make_maac",
    "qmix": "score_jax.baselines.qmix:make_qmix",
}


def builder(name: str) -> Callable[..., Algorithm]:
    """The builder registered under ``name`` (imports it on first use)."""
    if name not in REGISTRY:
        raise ValueError(f"unknown algorithm {name!r}; known: {sorted(REGISTRY)}")
    entry = REGISTRY[name]
    if isinstance(entry, str):
        import importlib

        module, func = entry.split(":")
        entry = getattr(importlib.import_module(module), func)
    return entry


def make(cfg, env, agent_index, key, pretrain: bool = True, log=print) -> Algorithm:
    return builder(cfg.algo)(cfg, env, agent_index, key, pretrain=pretrain, log=log)
