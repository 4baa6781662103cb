"""The pinned jax/flax/brax set runs brax's own SAC on one of our environments.

brax 0.14.2's training agents call ``jax.device_put_replicated`` (removed in jax 0.10); this
test fails if the pins drift to a set where that breaks. The single-agent baselines reuse
``brax.training.agents`` through ``envs.wrappers.BraxFlatEnv``.
"""

import jax
import numpy as np

import envs
from score_jax.agents.brax.flat_env import BraxFlatEnv


def test_brax_sac_trains_on_the_greenhouse_through_the_flat_wrapper():
    from brax.training.agents.sac import train as sac

    env = BraxFlatEnv(envs.make("greenhouse", season_days=20))
    assert env.action_size == 52
    progress = []
    make_policy, params, metrics = sac.train(
        environment=env,
        num_timesteps=480,
        episode_length=20,
        num_envs=8,
        batch_size=32,
        num_evals=2,
        num_eval_envs=2,
        min_replay_size=160,
        grad_updates_per_step=1,
        seed=0,
        progress_fn=lambda s, m: progress.append(s),
    )
    assert progress and np.isfinite(metrics["eval/episode_reward"])
    policy = make_policy(params, deterministic=True)
    state = env.reset(jax.random.PRNGKey(0))
    action, _ = policy(state.obs[None], jax.random.PRNGKey(1))
    assert action.shape == (1, 52) and bool(np.all(np.abs(np.asarray(action)) <= 1.0))
