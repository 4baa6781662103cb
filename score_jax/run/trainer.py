"""The off-policy training epoch shared by SCORE and every off-policy baseline.

Data parallel: with a ``Mesh`` whose axis is ``data`` (``run.sharding``), the environments and
each sampled batch are sharded along it and parameters, optimiser states and the replay
buffer are replicated; XLA inserts the gradient all-reduce.

One jitted ``epoch`` = ``lax.scan`` over ``steps_per_epoch`` vectorised environment steps; each
step acts in ``num_envs`` auto-resetting environments, writes the transitions to the replay
buffer and runs ``updates_per_step`` gradient updates of the algorithm (Alg. 1 lines 2-16).
Python only drives epochs: logging, evaluation, checkpoints.

An algorithm plugs in through ``agents.base.OffPolicyAlgorithm``: ``init``, ``act`` and
``update``; the update receives a replay batch and returns a new algorithm state and a dict
of metrics.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from envs.base import CompositeEnv, EnvState
from envs.wrappers import FINAL_OBS, AutoReset
from score_jax.agents.base import OffPolicyAlgorithm
from score_jax.agents.replay import (
    ReplayBuffer,
    Transition,
    replay_add,
    replay_init,
    replay_sample_nstep,
)
from score_jax.core.failures import fail_batch
from score_jax.core.spaces import agents_to_env_action, pad_width, sample_agent_actions
from score_jax.run.config import OffPolicyConfig
from score_jax.run.distributed import place_tree
from score_jax.run.exploration import shift_continuous


@struct.dataclass
class TrainState:
    agent: Any
    buffer: ReplayBuffer
    env_state: EnvState  # batched [num_envs], auto-resetting
    episode_return: jax.Array  # [num_envs] running return of the current episodes
    # [num_envs, n, max_dim] action the envs received last step (LAST failure mode)
    last_action: jax.Array
    explore_keys: jax.Array  # [num_envs, 2] each env's held exploration key (``exploration_hold``)
    key: jax.Array
    env_steps: jax.Array  # [] int32 transitions collected so far
    updates: jax.Array  # [] int32 gradient updates so far
    alive: jax.Array  # [] bool: False once this seed went non-finite (``SeedTrainer``)


@struct.dataclass
class EpochMetrics:
    agent: dict  # the algorithm's update metrics by name, averaged over the epoch's updates
    completed_return_sum: jax.Array  # [] sum of returns of episodes that ended this epoch
    completed_episodes: jax.Array  # [] number of such episodes
    reward_mean: jax.Array  # [] mean per-step reward this epoch
    finite: jax.Array  # [] bool: every loss and parameter is finite


def _all_finite(tree) -> jax.Array:
    leaves = [
        jnp.all(jnp.isfinite(x))
        for x in jax.tree.leaves(tree)
        if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.array(True)


class Trainer:
    """Builds the initial state and the jitted epoch for one (env, algorithm, config)."""

    def __init__(
        self,
        env: CompositeEnv,
        algo: OffPolicyAlgorithm,
        config: OffPolicyConfig,
        agent_index=None,
        mesh: Mesh | None = None,
    ):
        self.env = AutoReset(env)
        self.mesh = mesh
        if mesh is not None and config.num_envs % mesh.size:
            raise ValueError(
                f"num_envs={config.num_envs} must be a multiple of the "
                f"{mesh.size} devices of the mesh"
            )
        if mesh is not None and config.batch_size % mesh.size:
            raise ValueError(
                f"batch_size={config.batch_size} must be a multiple of the "
                f"{mesh.size} devices of the mesh"
            )
        self.space = env.space
        self.algo, self.config = algo, config
        self.agent_index = (
            np.arange(env.space.n) if agent_index is None else np.asarray(agent_index)
        )
        if len(self.agent_index) != algo.n_agents:
            raise ValueError(
                f"algorithm has {algo.n_agents} agents but agent_index has {len(self.agent_index)}"
            )
        # run.config.resolve has already resolved these for a run; None here (a trainer built
        # directly) means the environment's suggestion, as there.
        self.hold = env.hints.pick("exploration_hold", config.exploration_hold)
        self.updates_per_step = env.hints.pick("updates_per_step", config.updates_per_step)
        self.n_step = env.hints.pick("n_step", config.n_step)
        # [n_agents, width] the agents' real continuous columns (``exploration_shift``)
        space = env.space
        continuous = (space.dim_mask & ~space.discrete_mask)[self.agent_index]
        self.continuous = pad_width(continuous, algo.width, False)
        self.epoch = jax.jit(self._epoch)

    # -- state -------------------------------------------------------------------------
    def init(self, key: jax.Array, frozen=None) -> TrainState:
        """A fresh state from ``key``; ``frozen``: the algorithm's pretrained inputs of this seed
        (``Algorithm.pretrain``), None for their template."""
        return self.place(jax.jit(self.init_state)(key, frozen))

    def init_state(self, key: jax.Array, frozen=None) -> TrainState:
        """``init`` as a pure function (vmapped over seeds by ``SeedTrainer``), not placed."""
        key, key_agent, key_env = jax.random.split(key, 3)
        n, w, obs_size = self.algo.n_agents, self.algo.width, self.env.observation_size
        example = Transition(
            obs=jnp.zeros(obs_size),
            action=jnp.zeros((n, w)),
            reward=jnp.zeros(()),
            next_obs=jnp.zeros(obs_size),
            terminal=jnp.zeros(()),
            active=jnp.ones(n, bool),
        )
        num_envs = self.config.num_envs
        return TrainState(
            agent=self.algo.init(key_agent, frozen),
            buffer=replay_init(example, self.config.replay_capacity),
            env_state=jax.vmap(self.env.reset)(jax.random.split(key_env, num_envs)),
            episode_return=jnp.zeros(num_envs),
            last_action=jnp.broadcast_to(
                self.space.default_action(), (num_envs, self.space.n, self.space.max_dim)
            ),
            explore_keys=jax.random.split(jax.random.fold_in(key, 1), num_envs),
            key=key,
            env_steps=jnp.zeros((), jnp.int32),
            updates=jnp.zeros((), jnp.int32),
            alive=jnp.ones((), bool),
        )

    # -- data parallelism ------------------------------------------------------------------
    def place(self, state: TrainState) -> TrainState:
        """Shard the env batch along the mesh's ``data`` axis; replicate everything else."""
        if self.mesh is None:
            return state
        data, replicated = NamedSharding(self.mesh, P("data")), NamedSharding(self.mesh, P())
        return state.replace(
            agent=place_tree(state.agent, replicated),
            buffer=place_tree(state.buffer, replicated),
            key=place_tree(state.key, replicated),
            env_state=place_tree(state.env_state, data),
            episode_return=place_tree(state.episode_return, data),
            last_action=place_tree(state.last_action, data),
            explore_keys=place_tree(state.explore_keys, data),
            env_steps=place_tree(state.env_steps, replicated),
            updates=place_tree(state.updates, replicated),
            alive=place_tree(state.alive, replicated),
        )

    def _shard_batch(self, tree):
        if self.mesh is None:
            return tree
        return jax.lax.with_sharding_constraint(tree, NamedSharding(self.mesh, P("data")))

    # -- one vectorised step + its updates ------------------------------------------------
    def _step(self, carry: tuple[TrainState, Any], _):
        state, hyper = carry
        cfg = self.config
        key, key_act, key_rand, key_upd, key_fail = jax.random.split(state.key, 5)
        policy_action, explore_keys = self._explore(state, key_act)
        explore = state.env_steps < cfg.learning_starts
        action = jnp.where(
            explore,
            sample_agent_actions(
                self.space, self.agent_index, key_rand, (cfg.num_envs,), self.algo.width
            ),
            policy_action,
        )
        env_action, active = self._apply_train_failures(
            agents_to_env_action(self.space, action, self.agent_index), state.last_action, key_fail
        )
        env_state = jax.vmap(self.env.step)(state.env_state, env_action)
        final_obs = env_state.info[FINAL_OBS]
        # store what the environment received (a failed agent's replacement, padded to width)
        received = jnp.pad(
            env_action[:, self.agent_index],
            ((0, 0), (0, 0), (0, self.algo.width - self.space.max_dim)),
        )
        transition = Transition(
            obs=state.env_state.obs,
            action=jnp.where(active[..., None], action, received),
            reward=env_state.reward,
            next_obs=final_obs,
            terminal=env_state.done * (1.0 - env_state.truncated),
            active=active,
        )
        buffer = replay_add(state.buffer, transition)
        ret = state.episode_return + env_state.reward
        completed = jnp.sum(ret * env_state.done), jnp.sum(env_state.done)
        env_steps = state.env_steps + cfg.num_envs

        traced = {}  # do_updates' metric shapes, recorded while lax.cond traces it

        def do_updates(agent):
            def one(agent, k):
                k_sample, k_update = jax.random.split(k)
                batch = self._shard_batch(
                    replay_sample_nstep(
                        buffer,
                        k_sample,
                        cfg.batch_size,
                        self.n_step,
                        cfg.num_envs,
                        self._gamma(hyper),
                    )
                )
                return self.algo.update(agent, batch, k_update, hyper)

            agent, metrics = jax.lax.scan(
                one, agent, jax.random.split(key_upd, self.updates_per_step)
            )
            metrics = jax.tree.map(lambda m: jnp.mean(m, axis=0), metrics)
            traced["metrics"] = jax.tree.map(
                lambda m: jax.ShapeDtypeStruct(m.shape, m.dtype), metrics
            )
            return agent, metrics, jnp.float32(1.0)

        def skip(agent):
            # lax.cond traces the true branch first, so the update (the largest part of the
            # step) is traced once; the fallback covers a cond that traces one branch only
            metrics = traced.get("metrics") or jax.eval_shape(lambda a: do_updates(a)[1], agent)
            return (
                agent,
                jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), metrics),
                jnp.float32(0.0),
            )

        learn = (env_steps >= cfg.learning_starts) & (buffer.size >= cfg.batch_size)
        agent, metrics, did = jax.lax.cond(learn, do_updates, skip, state.agent)
        state = state.replace(
            agent=agent,
            buffer=buffer,
            env_state=env_state,
            episode_return=ret * (1.0 - env_state.done),
            key=key,
            last_action=env_action,
            explore_keys=explore_keys,
            env_steps=env_steps,
            updates=state.updates + self.updates_per_step * did.astype(jnp.int32),
        )
        return (state, hyper), (metrics, did, completed, jnp.mean(env_state.reward))

    def _gamma(self, hyper) -> jax.Array | None:
        """The algorithm's discount for n-step samples; None for one-step ones, which need none."""
        return hyper.gamma if self.n_step > 1 else None

    def _explore(self, state: TrainState, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The stochastic policy's actions ``[num_envs, n, w]`` and the envs' exploration keys.

        With ``hold > 1`` each env samples with its own key, redrawn when its episode step is a
        multiple of ``hold`` (0 right after a reset): the same noise relative to the current
        mean and logits for ``hold`` steps. ``act`` is vmapped over single environments, so this
        works for every algorithm's ``act`` unchanged.
        """
        if self.hold == 1:
            keys = state.explore_keys
            actions = self.algo.act(state.agent, state.env_state.obs, key, False)
        else:
            redraw = (state.env_state.t % self.hold) == 0
            keys = jnp.where(
                redraw[:, None], jax.random.split(key, self.config.num_envs), state.explore_keys
            )
            act_one = lambda obs, k: self.algo.act(state.agent, obs[None], k, False)[0]
            actions = jax.vmap(act_one)(state.env_state.obs, keys)
        std = self.config.exploration_shift
        if std > 0.0:
            # the shift is drawn apart from the policy's own noise, held with the env's key
            shift_keys = (
                jax.random.split(jax.random.fold_in(key, 1), self.config.num_envs)
                if self.hold == 1
                else jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
            )
            shift = lambda a, k: shift_continuous(a, self.continuous, k, std)
            actions = jax.vmap(shift)(actions, shift_keys)
        return actions, keys

    def _apply_train_failures(self, env_action, last_action, key):
        """Training-time failures through the shared failure function; returns
        ``(env action [B, n_env, max_dim], agent active mask [B, n_agents])``."""
        cfg = self.config
        n_agents = len(self.agent_index)
        if cfg.train_failures == 0:
            return env_action, jnp.ones((cfg.num_envs, n_agents), bool)
        controlled = np.isin(np.arange(self.space.n), self.agent_index)
        applied, active = fail_batch(
            self.space,
            env_action,
            last_action,
            key,
            cfg.train_failures,
            cfg.train_failure_mode,
            controlled,
        )
        return applied, active[:, self.agent_index]

    def _epoch(self, state: TrainState, hyper) -> tuple[TrainState, EpochMetrics]:
        (state, _), (metrics, did, completed, reward) = jax.lax.scan(
            self._step, (state, hyper), None, self.config.steps_per_epoch
        )
        n_did = jnp.maximum(jnp.sum(did), 1.0)
        mean_metrics = jax.tree.map(
            lambda m: jnp.sum(m * did.reshape((-1,) + (1,) * (m.ndim - 1)), axis=0) / n_did, metrics
        )
        finite = _all_finite(mean_metrics) & _all_finite(state.agent)
        return state, EpochMetrics(
            mean_metrics, jnp.sum(completed[0]), jnp.sum(completed[1]), jnp.mean(reward), finite
        )


class SeedTrainer:
    """K independent runs of one ``Trainer`` in one compiled program: every leaf of the
    ``TrainState`` gets a leading seed axis and the epoch is ``vmap``ped over it (PureJaxRL's
    ``jit(vmap(train))``), so the small kernels of one run become K-wide batched ones.

    A seed whose losses or parameters go non-finite is stopped: its agent state, step and update
    counters stay at their last finite values and ``alive`` turns False; the other seeds go on.

    Data parallelism (``mesh``): when K is a multiple of the device count the seed axis is
    sharded (whole runs per device: no communication at all); otherwise the inner ``Trainer``
    shards each seed's environments and batches (it was built with the mesh). In a distributed
    run the mesh holds every process's devices, the seeds are sharded over all of them and
    ``place`` makes global arrays (``run.distributed.place``).
    """

    def __init__(self, trainer: Trainer, num_seeds: int, mesh: Mesh | None = None):
        if num_seeds < 1:
            raise ValueError(f"num_seeds must be >= 1, got {num_seeds}")
        self.single, self.num_seeds = trainer, int(num_seeds)
        self.mesh = mesh if mesh is not None and num_seeds % mesh.size == 0 else None
        self.epoch = jax.jit(self._epoch)

    @property
    def shards(self) -> str:
        """What the ``data`` axis splits: ``seeds``, ``envs`` or ``nothing``."""
        if self.mesh is not None:
            return "seeds"
        return "envs" if self.single.mesh is not None else "nothing"

    def init(self, keys: jax.Array, frozen=None) -> TrainState:
        """``keys [K, 2]``; ``frozen``: pretrained inputs with a leading K axis (None: template)."""
        in_axes = (0, None if frozen is None else 0)
        return self.place(jax.jit(jax.vmap(self.single.init_state, in_axes))(keys, frozen))

    def place(self, state: TrainState) -> TrainState:
        if self.mesh is not None:
            return place_tree(state, NamedSharding(self.mesh, P("data")))
        if self.single.mesh is None:
            return state
        data = NamedSharding(self.single.mesh, P(None, "data"))
        replicated = NamedSharding(self.single.mesh, P())
        per_env = ("env_state", "episode_return", "last_action", "explore_keys")
        return state.replace(
            **{
                f.name: place_tree(
                    getattr(state, f.name), data if f.name in per_env else replicated
                )
                for f in dataclasses.fields(state)
            }
        )

    def _epoch(self, state: TrainState, hyper) -> tuple[TrainState, EpochMetrics]:
        new, metrics = jax.vmap(self.single._epoch, in_axes=(0, None))(state, hyper)
        ok = state.alive & metrics.finite

        def freeze(fresh, old):
            return jnp.where(ok.reshape((-1,) + (1,) * (fresh.ndim - 1)), fresh, old)

        new = new.replace(
            agent=jax.tree.map(freeze, new.agent, state.agent),
            env_steps=freeze(new.env_steps, state.env_steps),
            updates=freeze(new.updates, state.updates),
            alive=ok,
        )
        return new, metrics
