"""Full evaluation episodes under failures: one function used by the run's periodic
evaluations, the end-of-run report, the robustness sweep (which vmaps it over settings) and
every baseline; and the reference policies it compares with.

At each step ``n_failed`` of the controlled sub-spaces are drawn at random and fail with
``mode`` (§5.2.3): the environment receives the replacement from ``score_jax.core.failures``.
``n_failed`` and ``mode`` are arrays, so one compiled function serves every setting.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs.base import CompositeEnv, ReferencePolicy
from score_jax.agents.base import ActFn
from score_jax.core.failures import fail_batch
from score_jax.core.spaces import agents_to_env_action, pad_width, sample_agent_actions


@struct.dataclass
class EvalResult:
    returns: jax.Array  # [E] undiscounted episode returns
    lengths: jax.Array  # [E] steps until done (episode_length if never done)


def evaluate(
    env: CompositeEnv,
    act_fn: ActFn,
    key: jax.Array,
    n_episodes: int,
    agent_index,
    n_failed: jax.Array | int = 0,
    mode: jax.Array | int = 0,
) -> EvalResult:
    """Run ``n_episodes`` full episodes in parallel (``lax.scan`` over steps of ``vmap`` over
    episodes).

    Args:
      env: the environment (not auto-resetting).
      act_fn: the policy, batched over episodes.
      key: PRNG key (reset states, policy noise, failure draws).
      n_episodes: E, static.
      agent_index: ``[n_agents]`` sub-space of ``env.space`` controlled by each agent (static).
      n_failed: number of controlled sub-spaces that fail at each step (redrawn every step).
      mode: a ``FailureMode`` value.
    """
    space = env.space
    agent_index = np.asarray(agent_index)
    controlled = np.zeros(space.n, bool)
    controlled[agent_index] = True
    key_reset, key_run = jax.random.split(key)
    state = jax.vmap(env.reset)(jax.random.split(key_reset, n_episodes))
    last = jnp.broadcast_to(space.default_action(), (n_episodes, space.n, space.max_dim))

    def step(carry, key_t):
        state, last, ret, alive, length = carry
        key_act, key_fail = jax.random.split(key_t)
        action = agents_to_env_action(space, act_fn(state, key_act), agent_index)
        applied, _ = fail_batch(space, action, last, key_fail, n_failed, mode, controlled)
        state = jax.vmap(env.step)(state, applied)
        ret = ret + alive * state.reward
        length = length + alive
        alive = alive * (1.0 - state.done)
        return (state, applied, ret, alive, length), None

    zeros = jnp.zeros(n_episodes)
    carry = (state, last, zeros, jnp.ones(n_episodes), zeros)
    (_, _, ret, _, length), _ = jax.lax.scan(
        step, carry, jax.random.split(key_run, env.episode_length)
    )
    return EvalResult(ret, length)


def make_evaluator(
    env: CompositeEnv, policy: Callable, agent_index, n_episodes: int, seeds: bool = False
):
    """``evaluate`` compiled once with the agent's state an ARGUMENT (not a closed-over constant).

    ``policy(agent_state) -> act_fn``. Returns ``fn(agent_state, key, n_failed=0, mode=0) ->
    EvalResult``: evaluating a new set of parameters, or under other failures, reuses the same
    executable (closing over the parameters instead would recompile, and constant-fold the
    network, at every call). ``seeds=True``: ``agent_state`` and ``key`` have a leading seed
    axis (one key per seed) and the result is ``[K, E]``, all seeds in one vmapped call.
    """
    agent_index = np.asarray(agent_index)

    def fn(agent_state, key, n_failed=0, mode=0):
        return evaluate(env, policy(agent_state), key, n_episodes, agent_index, n_failed, mode)

    if seeds:
        return jax.jit(jax.vmap(fn, in_axes=(0, 0, None, None)))
    return jax.jit(fn)


def random_act_fn(space, agent_index, width: int) -> ActFn:
    """A uniformly random policy over the controlled sub-spaces (the 'random' reference)."""
    return lambda state, key: sample_agent_actions(
        space, agent_index, key, state.obs.shape[:1], width
    )


def default_act_fn(space, agent_index, width: int) -> ActFn:
    """Every controlled sub-space at its physical default (the 'default setpoints' reference)."""
    a = space.default_action()[np.asarray(agent_index)]
    a = pad_width(a, width)

    def act(state, key):
        return jnp.broadcast_to(a, (state.obs.shape[0], *a.shape))

    return act


def scripted_act_fn(reference: ReferencePolicy, agent_index, width: int) -> ActFn:
    """An environment's scripted policy (``env.reference_policies()``), batched over episodes,
    restricted to the agents' sub-spaces and padded to ``width``."""
    idx = np.asarray(agent_index)
    return lambda state, key: pad_width(jax.vmap(reference)(state)[:, idx], width)


def reference_policies(
    env: CompositeEnv, agent_index, width: int, planned: bool = False
) -> dict[str, ActFn]:
    """``random``, ``default`` and the environment's scripted policies (e.g. ``expert``); with
    ``planned`` also those it finds by planning (``env.planned_references``, e.g. the
    greenhouse's best constant and open-loop schedules for the decisions ``env`` takes)."""
    refs = {
        "random": random_act_fn(env.space, agent_index, width),
        "default": default_act_fn(env.space, agent_index, width),
    }
    scripted = dict(env.reference_policies())
    if planned:
        scripted.update(env.planned_references())
    for name, reference in scripted.items():
        refs[name] = scripted_act_fn(reference, agent_index, width)
    return refs
