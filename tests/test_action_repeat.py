"""ActionRepeat: a decision holds for k steps, returns are the wrapped env's, episodes end on
time."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.wrappers import ActionRepeat, unwrapped, with_action_repeat
from score_jax.run.config import OffPolicyConfig, TrainConfig, resolve


def test_repeat_sums_rewards_and_ends_with_the_wrapped_episode():
    env = envs.make("probe", episode_length=10)
    wrapped = ActionRepeat(env, 3)
    assert wrapped.episode_length == 4 and wrapped.space == env.space and unwrapped(wrapped) is env
    action = env.space.default_action()
    key = jax.random.PRNGKey(0)
    state = inner = env.reset(key)
    inner_rewards, wrapped_rewards, dones = [], [], []
    for _ in range(10):
        inner = env.step(inner, action)
        inner_rewards.append(float(inner.reward))
    for _ in range(4):
        state = jax.jit(wrapped.step)(state, action)
        wrapped_rewards.append(float(state.reward))
        dones.append(float(state.done))
    np.testing.assert_allclose(
        wrapped_rewards,
        [
            sum(inner_rewards[0:3]),
            sum(inner_rewards[3:6]),
            sum(inner_rewards[6:9]),
            inner_rewards[9],
        ],
        rtol=1e-5,
    )
    assert dones == [0.0, 0.0, 0.0, 1.0]
    assert (
        int(state.t) == 10
    )  # the last decision stopped at the episode's end (2 inner steps skipped)
    np.testing.assert_allclose(state.obs, inner.obs)


def test_repeat_one_is_the_env_itself_and_suggestions_resolve():
    env = envs.make("probe")
    assert with_action_repeat(env, 1) is env
    with pytest.raises(ValueError, match=">= 1"):
        ActionRepeat(env, 0)
    greenhouse = envs.make("greenhouse")
    assert resolve(TrainConfig(), greenhouse).action_repeat == greenhouse.hints.action_repeat == 8
    assert resolve(TrainConfig(action_repeat=2), greenhouse).action_repeat == 2
    assert resolve(TrainConfig(env="probe"), env).action_repeat == 1
    wrapped = ActionRepeat(greenhouse, 8)
    assert wrapped.hints.reward_scale == pytest.approx(greenhouse.hints.reward_scale / 8)
    assert wrapped.expert_action.__self__ is greenhouse  # other attributes are the wrapped env's
    with pytest.raises(ValueError, match="action_repeat"):
        resolve(TrainConfig(action_repeat=-1), greenhouse)
    # the update schedule is a hint too: one update per step on the greenhouse, two elsewhere
    assert resolve(TrainConfig(), greenhouse).updates_per_step == 1
    assert resolve(TrainConfig(env="probe"), env).updates_per_step == 2
    given = TrainConfig(off_policy=OffPolicyConfig(updates_per_step=3))
    assert resolve(given, greenhouse).updates_per_step == 3
    with pytest.raises(ValueError, match="updates_per_step"):
        resolve(TrainConfig(off_policy=OffPolicyConfig(updates_per_step=0)), greenhouse)
    # and so are the TD targets' steps: three on the greenhouse, one elsewhere
    assert resolve(TrainConfig(), greenhouse).n_step == 3
    assert resolve(TrainConfig(env="probe"), env).n_step == 1
    assert resolve(TrainConfig(off_policy=OffPolicyConfig(n_step=1)), greenhouse).n_step == 1
    with pytest.raises(ValueError, match="n_step"):
        resolve(TrainConfig(off_policy=OffPolicyConfig(n_step=0)), greenhouse)


def test_repeated_greenhouse_season_returns_the_daily_return():
    """A constant policy gets the same season return whatever the decision interval."""
    env = envs.make("greenhouse")
    wrapped = ActionRepeat(env, 8)
    action = env.space.default_action()

    def season(e, n):
        def step(c, _):
            s, r = c
            s = e.step(s, action)
            return (s, r + s.reward), s.done

        (s, r), done = jax.lax.scan(step, (e.reset(jax.random.PRNGKey(0)), 0.0), None, n)
        return r, done

    daily, _ = jax.jit(lambda: season(env, env.episode_length))()
    weekly, done = jax.jit(lambda: season(wrapped, wrapped.episode_length))()
    assert float(weekly) == pytest.approx(float(daily), rel=1e-5)
    assert float(done[-1]) == 1.0 and float(jnp.sum(done)) == 1.0
