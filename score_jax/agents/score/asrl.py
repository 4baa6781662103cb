"""Action space representation learning (§4.1): collect observation sets, train the HVAE.

Data collection, as in the paper: for every sub-space i, draw k random fixings a_{-i}^k of
all the other sub-spaces and, under each, j random sub-actions a_{i,j}^k. Our choices where the
paper is silent:

* Each fixing k starts from its own environment state, reached by a random-policy warm-up of
  random length in ``[0, warmup_steps]`` (e.g. a random day of the greenhouse season), so the
  set covers diverse states. The j sub-actions of one fixing all start from that SAME state:
  a controlled experiment where only a_i differs.
* The composite action is kept for the t further steps whose observations are the
  prediction targets (so they show the sustained effect of the sub-action).
* A warm-up step that would end the episode is discarded (the state stays put), so every
  set element comes from a live episode; ``future_mask`` marks steps after an ending.
* Sub-spaces with ``fixed_default`` True are held at their default in the warm-up and the
  fixings (training on a subset: those sub-spaces "do not exist yet"), but are varied when
  they are themselves the studied sub-space (``embed_new_spaces`` for transfer, §4.3).

Everything is one jit: vmap over (i, k, j), ``lax.scan`` over steps.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from score_jax.agents.score.config import ScoreConfig
from score_jax.agents.score.networks import FrozenInputs
from score_jax.core.spaces import pad_width
from score_jax.networks.hvae import (
    HVAE,
    HVAEConfig,
    HVAEMetrics,
    ObservationSets,
    hvae_train_step,
    init_hvae,
    make_optimizer,
    observation_set_shapes,
    space_embeddings,
)


class HVAEResult(NamedTuple):
    """Output of ``train_hvae``.

    Attributes:
      model: the HVAE module (static structure).
      params: its trained ``"params"``.
      c: ``[len(agents), c_dim]`` embeddings of the trained sub-spaces (posterior means).
      metrics: HVAEMetrics of the last training step.
      history: ``[steps]`` loss (negative ELBO per observation, weighted, plus the weighted
        action-reconstruction term) of every step.
      elbo_history: ``[steps]`` eq. 2's ELBO per observation of every step (no action term).
    """

    model: HVAE
    params: dict
    c: jax.Array
    metrics: HVAEMetrics
    history: np.ndarray
    elbo_history: np.ndarray


def default_warmup_steps(env, t: int) -> int:
    """Longest warm-up that still leaves room for 1 + t steps (capped at 200)."""
    return int(max(0, min(env.episode_length - t - 2, 200)))


def _collect(
    env,
    key,
    agents: tuple,
    k: int,
    j: int,
    t: int,
    action_width: int,
    warmup_steps: int,
    fixed_default,
):
    space = env.space
    n = space.n
    agents_arr = jnp.asarray(agents, jnp.int32)
    S = len(agents)
    default = space.default_action()  # [n, max_dim]
    keep_default = fixed_default[:, None]  # [n, 1]

    def random_policy(key):  # uniform, except sub-spaces held at their default
        return jnp.where(keep_default, default, space.sample(key))

    def warm_up(key):
        key_reset, key_len, key_steps = jax.random.split(key, 3)
        state = env.reset(key_reset)
        length = jax.random.randint(key_len, (), 0, warmup_steps + 1)

        def body(state, x):
            step_i, key_step = x
            nxt = env.step(state, random_policy(key_step))
            take = (step_i < length) & (nxt.done < 0.5)
            return jax.tree_util.tree_map(lambda a, b: jnp.where(take, a, b), nxt, state), None

        if warmup_steps > 0:
            state, _ = jax.lax.scan(
                body, state, (jnp.arange(warmup_steps), jax.random.split(key_steps, warmup_steps))
            )
        return state

    def rollout(state, action):
        """Apply ``action`` 1 + t times: (o after the first step, t future obs, their mask)."""

        def body(carry, _):
            state, alive = carry
            nxt = env.step(state, action)
            return (nxt, alive & (nxt.done < 0.5)), (nxt.obs, alive)

        # alive_before[s]: no step before step s ended the episode, i.e. obs s is valid.
        _, (obs_seq, alive_before) = jax.lax.scan(
            body, (state, jnp.array(True)), None, length=1 + t
        )
        return obs_seq[0], obs_seq[1:], alive_before[1:]

    def one_fixing(i, key):
        key_warm, key_fix, key_sub = jax.random.split(key, 3)
        state = warm_up(key_warm)
        fixing = random_policy(key_fix)  # a_{-i}^k
        sub = space.sample(key_sub, (j,))[:, i]  # [j, max_dim] a_{i,j}^k
        actions = jnp.broadcast_to(fixing, (j, n, space.max_dim)).at[:, i].set(sub)
        obs, future, future_mask = jax.vmap(rollout, in_axes=(None, 0))(state, actions)
        prev = jnp.broadcast_to(state.obs, obs.shape)
        return obs, prev, sub, future, future_mask

    def one_space(i, key):
        obs, prev, sub, future, fmask = jax.vmap(one_fixing, in_axes=(None, 0))(
            i, jax.random.split(key, k)
        )
        flat = lambda x: x.reshape(k * j, *x.shape[2:])
        return flat(obs), flat(prev), flat(sub), flat(future), flat(fmask)

    obs, prev, sub, future, fmask = jax.vmap(one_space)(agents_arr, jax.random.split(key, S))
    dim_mask = pad_width(jnp.asarray(space.dim_mask)[agents_arr], action_width, False)
    return ObservationSets(
        obs=obs.astype(jnp.float32),
        prev_obs=prev.astype(jnp.float32),
        actions=pad_width(sub, action_width),
        dim_mask=dim_mask,
        future=future.astype(jnp.float32),
        future_mask=fmask,
        set_mask=jnp.ones((S, k * j), bool),
        group=jnp.broadcast_to(jnp.repeat(jnp.arange(k, dtype=jnp.int32), j), (S, k * j)),
    )


def collect_observation_sets(
    env,
    key: jax.Array,
    agents: Sequence[int],
    k: int,
    j: int,
    t: int,
    action_width: int,
    warmup_steps: int | None = None,
    fixed_default: jax.Array | None = None,
) -> ObservationSets:
    """Observation sets O_i of the sub-spaces ``agents`` (§4.1), one jitted call.

    Args:
      env: a CompositeEnv (hashable; used as a static argument).
      key: PRNG key, or ``[K, 2]`` keys: K independent collections in one call (leading K axis
        on every field of the result).
      agents: indices of the sub-spaces to collect for (S of them).
      k: number of random fixings a_{-i}^k of the other sub-spaces per sub-space.
      j: number of random sub-actions a_{i,j}^k per fixing.
      t: number of future observations recorded after each transition.
      action_width: padded action width (>= ``env.space.max_dim``).
      warmup_steps: longest random-policy warm-up (a random length in [0, warmup_steps] per
        fixing); ``None`` -> ``default_warmup_steps(env, t)``.
      fixed_default: ``[n]`` bool, sub-spaces held at their default (``None``: none).

    Returns:
      ObservationSets with ``S = len(agents)``, ``m = k * j``.
    """
    space = env.space
    agents = tuple(int(a) for a in agents)
    if not agents or any(not 0 <= a < space.n for a in agents):
        raise ValueError(f"agents must be non-empty indices in [0, {space.n}), got {list(agents)}")
    if action_width < space.max_dim:
        raise ValueError(
            f"action_width={action_width} is smaller than the space's max_dim={space.max_dim}"
        )
    if min(k, j) < 1 or t < 0:
        raise ValueError(f"need k >= 1, j >= 1, t >= 0; got k={k}, j={j}, t={t}")
    if warmup_steps is None:
        warmup_steps = default_warmup_steps(env, t)
    fixed = (
        jnp.zeros((space.n,), bool) if fixed_default is None else jnp.asarray(fixed_default, bool)
    )
    if fixed.shape != (space.n,):
        raise ValueError(f"fixed_default must have shape ({space.n},), got {fixed.shape}")
    static = (agents, int(k), int(j), int(t), int(action_width), int(warmup_steps))
    return _collector(env, static, batched=jnp.ndim(key) > 1)(key, fixed)


# One compiled collector per (environment object, static sizes). Environments may hold arrays
# (weather, parameters) and then are not hashable, so they are keyed by identity and the
# entry keeps the environment alive (an id is never reused while its object lives).
_COLLECTORS: dict[tuple, tuple[object, Callable]] = {}


def _collector(env, static: tuple, batched: bool = False) -> Callable:
    cache_key = (id(env), static, batched)
    hit = _COLLECTORS.get(cache_key)
    if hit is None or hit[0] is not env:
        collect = lambda key, fixed: _collect(env, key, *static, fixed)
        if batched:
            collect = jax.vmap(collect, in_axes=(0, None))
        hit = (env, jax.jit(collect))
        _COLLECTORS[cache_key] = hit
    return hit[1]


def train_hvae(
    env,
    key: jax.Array,
    config: HVAEConfig,
    agents: Sequence[int],
    k: int,
    j: int,
    steps: int,
    action_width: int,
    fixed_default: jax.Array | None = None,
    progress: Callable[[int, HVAEMetrics], None] | None = None,
    warmup_steps: int | None = None,
    log_every: int = 100,
) -> HVAEResult:
    """Collect observation sets of ``agents`` and train the HVAE on eq. 2 for ``steps`` steps.

    ``key``: one PRNG key, or ``[K, 2]`` keys: K independent trainings (independent data, init
    and sampling) in one vmapped program, every field of the result with a leading K axis
    (``history [K, steps]``). ``progress(step, metrics)`` is called every ``log_every`` steps and
    at the end (with the metrics averaged over the K trainings).
    """
    single = jnp.ndim(key) == 1
    keys = key[None] if single else key
    split3 = jax.vmap(lambda kk: jax.random.split(kk, 3))(keys)
    key_data, key_init, key_train = split3[:, 0], split3[:, 1], split3[:, 2]
    sets = collect_observation_sets(
        env, key_data, agents, k, j, config.predict_steps, action_width, warmup_steps, fixed_default
    )
    model = HVAE(config, env.observation_size, action_width)
    optimizer = make_optimizer(config)

    @jax.jit
    def start(key_init, key_train, sets):
        # one compiled program: op by op (flax's init under vmap), this start took longer
        # than the HVAE steps of a short ASRL
        params = jax.vmap(lambda kk, s: init_hvae(model, kk, s))(key_init, sets)
        step_keys = jax.vmap(lambda kk: jax.random.split(kk, steps))(key_train)  # [K, steps, 2]
        return params, jax.vmap(optimizer.init)(params), jnp.swapaxes(step_keys, 0, 1)

    params, opt_state, step_keys = start(key_init, key_train, sets)
    step_keys = np.asarray(step_keys)  # sliced on the host: no dispatch per step
    step = jax.jit(jax.vmap(hvae_train_step(model, optimizer)))
    losses, elbos, metrics = [], [], None
    for i, keys_i in enumerate(step_keys):  # [steps, K, 2]: one host-side slice per step
        params, opt_state, metrics = step(params, opt_state, sets, keys_i)
        losses.append(metrics.loss)
        elbos.append(metrics.elbo)
        if progress is not None and ((i + 1) % log_every == 0 or i + 1 == steps):
            progress(i + 1, jax.tree.map(lambda m: jnp.mean(m), metrics))
    # op by op, as in the runs measured so far: compiled as one program, XLA fuses it and the
    # codes move in their last bits (and with them every run's numbers)
    c = jax.vmap(lambda p, s: space_embeddings(model, p, s))(params, sets)
    history, elbo_history = np.asarray(jnp.stack(losses, 1)), np.asarray(jnp.stack(elbos, 1))
    result = HVAEResult(model, params, c, metrics, history, elbo_history)
    if single:
        squeeze = lambda tree: jax.tree.map(lambda x: x[0], tree)
        result = HVAEResult(
            model, squeeze(params), c[0], squeeze(metrics), history[0], elbo_history[0]
        )
    return result


def embed_new_spaces(
    env,
    model: HVAE,
    params: dict,
    key: jax.Array,
    agents: Sequence[int],
    k: int,
    j: int,
    warmup_steps: int | None = None,
    fixed_default: jax.Array | None = None,
) -> jax.Array:
    """Embeddings ``[len(agents), c_dim]`` of (possibly unseen) sub-spaces with the FROZEN HVAE
    (§4.3).

    Collects their observation sets in ``env`` (which now contains them) exactly as in
    training and returns the posterior means of q_phi(c | O_i).
    """
    sets = collect_observation_sets(
        env,
        key,
        agents,
        k,
        j,
        model.config.predict_steps,
        model.action_width,
        warmup_steps,
        fixed_default,
    )
    return space_embeddings(model, params, sets)


def pretrain(
    env, agent_index, cfg: ScoreConfig, width: int, keys: jax.Array, log=print, fixed_default=None
) -> FrozenInputs:
    """The ASRL stage (§4.1): the HVAE trained on random-policy observation sets of the agents'
    sub-spaces, for every seed at once: ``keys [K, 2]`` -> FrozenInputs with a leading K axis."""
    if not cfg.critic.asrl:
        return FrozenInputs(None, None)

    contrast = cfg.hvae.code_contrast_weight > 0

    def progress(step, m):
        log(
            f"  ASRL step {step}/{cfg.asrl_steps}: ELBO (eq. 2) {float(m.elbo):.2f} "
            f"(recon {float(m.recon):.2f}, pred {float(m.pred):.2f}, KL_z {float(m.kl_z):.2f}, "
            f"KL_c {float(m.kl_c):.2f}); action recon NLL {float(m.act):.2f}; "
            + (f"code contrast {float(m.contrast):.3f}; " if contrast else "")
            + f"loss {float(m.loss):.2f}"
        )

    result = train_hvae(
        env,
        keys,
        cfg.hvae,
        agents=[int(i) for i in agent_index],
        k=cfg.asrl_k,
        j=cfg.asrl_j,
        steps=cfg.asrl_steps,
        action_width=width,
        fixed_default=fixed_default,
        progress=progress,
        log_every=max(cfg.asrl_steps // 4, 1),
    )
    return FrozenInputs(result.params, result.c)


def frozen_template(env, agent_index, cfg: ScoreConfig, width: int) -> FrozenInputs:
    """Shapes of the ASRL outputs without running ASRL (filled in by a checkpoint restore).

    ``jax.eval_shape`` of the HVAE's init on observation sets of ``observation_set_shapes``
    (a test checks them against the collector's): nothing is computed, and the environment is
    not traced (on the greenhouse that trace took seconds per restore).
    """
    if not cfg.critic.asrl:
        return FrozenInputs(None, None)
    model = HVAE(cfg.hvae, env.observation_size, width)
    agents = [int(i) for i in agent_index]
    sets = observation_set_shapes(
        env.observation_size, len(agents), 1, 2, cfg.hvae.predict_steps, width
    )
    shapes = jax.eval_shape(lambda key, s: init_hvae(model, key, s), jax.random.PRNGKey(0), sets)
    params = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
    return FrozenInputs(params, jnp.zeros((len(agents), cfg.hvae.space_embed_dim)))
