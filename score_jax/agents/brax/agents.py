"""Single-agent baselines trained by brax (§5.1): ``--algo sac`` and ``--algo ppo``.

The composite space is flattened to one ``[total_dim]`` action (``agents.brax.flat_env``) and
``brax.training.agents.sac.train`` / ``ppo.train`` train it unchanged, from a policy whose
output layer starts small and, with the default prior, at the defaults (``mlp_start``); H-PPO
(``agents.brax.hppo``) reuses the PPO loop with its own networks. brax runs its own loop, so
these algorithms plug into the run layer through ``Algorithm.train_external`` (the run layer's
external driver writes the metrics, shows progress and checkpoints the final policy).

The saved agent state is brax's inference parameters: ``(normalizer, policy)`` for SAC and
``(normalizer, policy, value)`` for PPO / H-PPO. Their networks cover every sub-space of the
full space (fixed width): a ``--subspaces`` run keeps the unseen heads and treats them with
the transfer variant (``agents.variants``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from brax.training import networks as brax_networks
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as brax_ppo
from brax.training.agents.sac import networks as sac_networks
from brax.training.agents.sac import train as brax_sac

from score_jax.agents import variants
from score_jax.agents.base import Algorithm, BuildContext, OffPolicyAlgorithm, deterministic_policy
from score_jax.agents.brax.config import SingleAgentConfig
from score_jax.agents.brax.flat_env import BraxFlatEnv
from score_jax.networks.actor import default_offset

NAN = float("nan")


SAC_METRICS = ("updates", "critic_loss", "actor_loss", "alpha", "eval_return")
PPO_METRICS = ("updates", "critic_loss", "actor_loss", "entropy", "eval_return")


def make_sac(sc: SingleAgentConfig, ctx: BuildContext) -> Algorithm:
    """brax SAC (tanh-normal policy over the flat action, twin Q, learned temperature)."""
    factory = functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=tuple(sc.hidden))
    return build(sc, ctx, "sac", "sac", factory, mlp_head_mask, mlp_start)


def make_ppo(sc: SingleAgentConfig, ctx: BuildContext) -> Algorithm:
    """brax PPO (tanh-normal policy over the flat action, state-value critic, GAE)."""
    hidden = tuple(sc.hidden)
    factory = functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=hidden,
        value_hidden_layer_sizes=hidden,
    )
    return build(sc, ctx, "ppo", "ppo", factory, mlp_head_mask, mlp_start)


def _last_layer(params) -> str:
    """Name of the output layer of brax's MLP policy (``hidden_<L>``)."""
    return max(params["params"], key=lambda name: int(name.split("_")[-1]))


def mlp_start(space, prior: np.ndarray, sc: SingleAgentConfig) -> Callable:
    """``start(params) -> params``: the initial parameters of brax's tanh-normal MLP policy
    (``[..., 2 total_dim]`` = flat means, then raw scales) with the default prior.

    The output layer's kernel is scaled by ``sc.head_init_scale`` and the mean bias of the
    flat columns of the sub-spaces marked in ``prior [n]`` set to ``atanh(default)`` (the
    offset SCORE's actors add, ``networks.actor.default_offset``): a fresh policy's
    deterministic action ``tanh(mean)`` is the default on those columns (a discrete dim's
    flat column lands on its default grid value, where ``BraxFlatEnv`` snaps it) and
    mid-range on the others. The bias is a parameter, so the offset trains like the rest.
    """
    cols = variants.flat_columns(space, prior)
    default = np.asarray(default_offset(space.flatten(space.default_action())))
    offset = np.concatenate([np.where(cols, default, 0.0), np.zeros(space.total_dim)])

    def start(params):
        last = _last_layer(params)
        layer = params["params"][last]
        layer = {"kernel": layer["kernel"] * sc.head_init_scale, "bias": layer["bias"] + offset}
        return {**params, "params": {**params["params"], last: layer}}

    return start


def starting_at(factory: Callable, start: Callable) -> Callable:
    """``factory`` whose policy network's ``init`` passes through ``start(params) -> params``
    (how the brax baselines get the default prior and the small output layer)."""

    def make(*args, **kwargs):
        nets = factory(*args, **kwargs)
        init = nets.policy_network.init
        return nets.replace(
            policy_network=brax_networks.FeedForwardNetwork(
                init=lambda key: start(init(key)), apply=nets.policy_network.apply
            )
        )

    return make


def mlp_head_mask(space, unseen: np.ndarray, params) -> dict:
    """Unseen heads of brax's tanh-normal MLP policy: the output columns (mean and scale) of the
    unseen sub-spaces' flat dims in its last Dense layer (``hidden_<L>``)."""
    cols = np.tile(variants.flat_columns(space, unseen), 2)
    layers = params["params"]
    last = _last_layer(params)
    return {
        "params": {
            name: (
                {"kernel": cols[None, :], "bias": cols}
                if name == last
                else jax.tree.map(lambda _: np.zeros((), bool), sub)
            )
            for name, sub in layers.items()
        }
    }


def deviation(dist, params: jax.Array, target: jax.Array) -> jax.Array:
    """Squared deviation per flat dim ``[..., total_dim]`` of the deterministic action from
    ``target``."""
    if hasattr(dist, "deviation"):  # the composite distribution of H-PPO
        return dist.deviation(params, target)
    loc = jnp.split(params, 2, axis=-1)[0]  # brax's tanh-normal: [mean, raw scale]
    return (jnp.tanh(loc) - target) ** 2


def variant_factory(
    factory: Callable, space, seen: np.ndarray, variant: str, coef: float, head_mask: Callable
) -> Callable:
    """``factory`` whose policy forward pass carries the transfer variant of the unseen heads."""
    unseen = ~seen
    cols = variants.flat_columns(space, unseen)
    target = space.flatten(space.default_action())

    def make(*args, **kwargs):
        nets = factory(*args, **kwargs)
        dist = nets.parametric_action_distribution
        dev = lambda y: jnp.sum(jnp.where(cols, deviation(dist, y, target), 0.0), axis=-1)
        apply = variants.variant_apply(
            nets.policy_network.apply, variant, lambda p: head_mask(space, unseen, p), dev, coef
        )
        return nets.replace(
            policy_network=brax_networks.FeedForwardNetwork(
                init=nets.policy_network.init, apply=apply
            )
        )

    return make


def build(
    sc: SingleAgentConfig,
    ctx: BuildContext,
    name: str,
    loop: str,
    factory: Callable,
    head_mask: Callable,
    start: Callable,
) -> Algorithm:
    """An ``Algorithm`` trained by brax's ``loop`` ("sac" | "ppo") with networks from ``factory``.

    ``start(space, prior [n], sc) -> (params -> params)``: the policy's initial parameters with
    the default prior of the sub-spaces marked in ``prior`` (``mlp_start``, ``hppo.hppo_start``).
    ``policy(agent) -> act_fn(env_state [E], key) -> [E, n_agents, max_dim]``: the deterministic
    flat action, un-flattened, rows of the controlled sub-spaces.
    """
    env, space = ctx.env, ctx.space
    variant = sc.transfer_variant or "plain"  # fixed width: a subset run always has one
    variants.check_variant(variant)
    idx = np.asarray(ctx.agent_index)
    seen = variants.seen_mask(space, idx)
    # The network covers every sub-space. The heads of those a subset run does not control
    # start without the prior: they are what transfer.py later fine-tunes as the new
    # sub-spaces' policies, which start untrained (§4.3), as the new actors of SCORE do.
    prior = np.zeros(space.n, bool)
    prior[idx] = ctx.prior_mask
    factory = starting_at(factory, start(space, prior, sc))
    normalize = running_statistics.normalize if sc.normalize_observations else (lambda x, y: x)
    nets = factory(env.observation_size, space.total_dim, preprocess_observations_fn=normalize)
    dist = nets.parametric_action_distribution

    def init(key, frozen=None):
        """The saved agent's structure: brax's inference parameters, freshly initialised."""
        key_policy, key_value = jax.random.split(key)
        normalizer = running_statistics.init_state(
            specs.Array((env.observation_size,), jnp.dtype("float32"))
        )
        agent = (normalizer, nets.policy_network.init(key_policy))
        return agent + (nets.value_network.init(key_value),) if loop == "ppo" else agent

    def act(agent, obs, key, deterministic):
        """``obs [B, obs] -> [B, n_agents, max_dim]``."""
        params = nets.policy_network.apply(agent[0], agent[1], obs)
        flat = dist.mode(params) if deterministic else dist.sample(params, key)
        return space.unflatten(flat)[..., idx, :]

    def train_external(total_steps: int, report, initial, evaluate=None, seed: int | None = None):
        """brax's loop from ``initial`` with brax's seed ``seed`` (default: the run's);
        ``evaluate(agent) -> return`` runs after every PPO epoch."""
        seed = ctx.seed if seed is None else int(seed)
        subset = not seen.all()
        train_factory = (
            variant_factory(factory, space, seen, variant, sc.penalty_coef, head_mask)
            if subset
            else factory
        )
        brax_env = BraxFlatEnv(env, controlled=seen if subset else None)
        if loop == "sac":
            return _train_sac(sc, ctx, brax_env, total_steps, train_factory, report, initial, seed)
        return _train_ppo(
            sc, ctx, brax_env, total_steps, train_factory, report, initial, evaluate, seed
        )

    off = OffPolicyAlgorithm(name, init, act, None, None, len(idx), space.max_dim)
    metrics = SAC_METRICS if loop == "sac" else PPO_METRICS
    return Algorithm(
        name,
        off,
        deterministic_policy(act),
        nets,
        grow=keep_agent,
        train_external=train_external,
        metric_names=metrics,
    )


def keep_agent(source, template, plan, key):
    """Transfer of a fixed-width baseline (§5.2.4, ``transfer.py``): the network already has a
    head for every sub-space, so fine-tuning on the full space starts from the trained
    parameters as they are (``template`` has the same structure)."""
    return source


def _reward_scale(sc: SingleAgentConfig, env) -> float:
    return float(env.hints.reward_scale if sc.reward_scaling is None else sc.reward_scaling)


def _epochs(sc: SingleAgentConfig, ctx: BuildContext, total: int, steps_per_iteration: int) -> int:
    """brax epochs: one per ``--eval-every`` steps if set, else ``single.epochs``; never more
    than there are training iterations (brax rounds each epoch up to whole iterations)."""
    wanted = math.ceil(total / ctx.eval_every) if ctx.eval_every else sc.epochs
    return max(1, min(wanted, total // steps_per_iteration))


def _value(metrics: dict, name: str) -> float:
    return float(metrics[name]) if name in metrics else NAN


def _train_ppo(
    sc: SingleAgentConfig,
    ctx: BuildContext,
    brax_env,
    total: int,
    factory,
    report,
    initial,
    evaluate=None,
    seed: int = 0,
):
    """brax's PPO loop, started from ``initial`` = ``(normalizer, policy, value)``.

    ``evaluate(agent) -> return`` (when ``--eval-every`` is set) runs after every epoch on the
    parameters brax hands to ``policy_params_fn``: the project's own deterministic evaluation
    (as for SCORE, handed over by the run layer) instead of brax's evaluator, so evaluating adds no
    program to brax's and the training program is the same with or without it. The evaluated
    parameters go to ``report`` too (the run keeps the best-evaluated policy).
    """
    p = sc.ppo
    per_iteration = p.batch_size * p.num_minibatches * p.unroll_length
    epochs = _epochs(sc, ctx, total, per_iteration)
    last_eval = {}

    def on_params(step, make_policy, params):
        if evaluate is None:
            return
        if (
            step == 0
        ):  # the starting policy (brax reports no training metrics before the first epoch)
            report(0, {"updates": 0, "eval_return": evaluate(params)}, params)
        else:
            last_eval[int(step)] = (evaluate(params), params)

    def progress(step, m):
        entropy = -_value(m, "training/entropy_loss") / p.entropy_cost if p.entropy_cost else NAN
        eval_return, params = last_eval.get(int(step), (NAN, None))
        report(
            int(step),
            {
                "updates": step // per_iteration * p.num_minibatches * p.updates_per_batch,
                "critic_loss": _value(m, "training/v_loss"),
                "actor_loss": _value(m, "training/policy_loss"),
                "entropy": entropy,
                "eval_return": eval_return,
            },
            params,
        )

    _, params, _ = brax_ppo.train(
        environment=brax_env,
        num_timesteps=total,
        episode_length=ctx.env.episode_length,
        num_envs=sc.num_envs,
        learning_rate=sc.learning_rate,
        entropy_cost=p.entropy_cost,
        discounting=sc.discounting,
        unroll_length=p.unroll_length,
        batch_size=p.batch_size,
        num_minibatches=p.num_minibatches,
        num_updates_per_batch=p.updates_per_batch,
        normalize_observations=sc.normalize_observations,
        reward_scaling=_reward_scale(sc, ctx.env),
        clipping_epsilon=p.clipping_epsilon,
        gae_lambda=p.gae_lambda,
        max_grad_norm=p.max_grad_norm,
        network_factory=factory,
        seed=seed,
        num_evals=epochs + 1,
        run_evals=False,
        progress_fn=progress,
        policy_params_fn=on_params,
        restore_params=initial,
    )
    return params


def _train_sac(
    sc: SingleAgentConfig,
    ctx: BuildContext,
    brax_env,
    total: int,
    factory,
    report,
    initial,
    seed: int,
):
    """brax's SAC loop, its policy started from ``initial[1]`` (the normaliser statistics and the Q
    networks start from brax's own initialisation: a fine-tuning run re-learns its Q networks)."""
    s = sc.sac
    if s.min_replay_size >= total:
        raise ValueError(
            f"--single.sac.min-replay-size ({s.min_replay_size}) must be below the run's env "
            f"steps ({total})"
        )
    prefill = -(-s.min_replay_size // sc.num_envs) * sc.num_envs
    epochs = _epochs(sc, ctx, total - prefill, sc.num_envs)

    def progress(step, m):
        report(
            int(step),
            {
                "updates": max(0, step - prefill) // sc.num_envs * s.grad_updates_per_step,
                "critic_loss": _value(m, "training/critic_loss"),
                "actor_loss": _value(m, "training/actor_loss"),
                "alpha": _value(m, "training/alpha"),
                "eval_return": _value(m, "eval/episode_reward"),
            },
        )

    _, params, _ = brax_sac.train(
        environment=brax_env,
        num_timesteps=total,
        episode_length=ctx.env.episode_length,
        num_envs=sc.num_envs,
        num_eval_envs=ctx.eval_episodes,
        learning_rate=sc.learning_rate,
        discounting=sc.discounting,
        seed=seed,
        batch_size=s.batch_size,
        num_evals=epochs + 1,
        normalize_observations=sc.normalize_observations,
        reward_scaling=_reward_scale(sc, ctx.env),
        tau=s.tau,
        min_replay_size=s.min_replay_size,
        max_replay_size=min(s.replay_capacity, total),
        grad_updates_per_step=s.grad_updates_per_step,
        deterministic_eval=True,
        network_factory=_starting_from(factory, initial[1]),
        progress_fn=progress,
    )
    return params


def _starting_from(factory: Callable, policy_params) -> Callable:
    """``factory`` whose policy network initialises to ``policy_params``: how a SAC run starts
    from given parameters (brax 0.14.2's ``restore_checkpoint_path`` swaps in unreplicated
    arrays after replicating the state, which its pmap then rejects)."""

    def make(*args, **kwargs):
        nets = factory(*args, **kwargs)
        return nets.replace(
            policy_network=brax_networks.FeedForwardNetwork(
                init=lambda key: policy_params, apply=nets.policy_network.apply
            )
        )

    return make
