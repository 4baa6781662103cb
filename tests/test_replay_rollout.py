"""Replay ring buffer, auto-reset, subset-agent actions and evaluation under failures (probe
env)."""

import jax
import jax.numpy as jnp
import numpy as np

import envs
from envs.wrappers import AutoReset
from score_jax.agents.replay import (
    Transition,
    continuation,
    replay_add,
    replay_init,
    replay_sample,
    replay_sample_nstep,
)
from score_jax.core.failures import FailureMode
from score_jax.core.spaces import agents_to_env_action, sample_agent_actions
from score_jax.run.episodes import default_act_fn, evaluate


def _transitions(start, b):
    v = jnp.arange(start, start + b, dtype=jnp.float32)
    return Transition(
        obs=v[:, None],
        action=jnp.zeros((b, 2, 1)),
        reward=v,
        next_obs=v[:, None] + 1,
        terminal=jnp.zeros(b),
        active=jnp.ones((b, 2), bool),
    )


def test_replay_ring_overwrites_oldest():
    example = jax.tree.map(lambda x: x[0], _transitions(0, 1))
    buf = replay_init(example, capacity=5)
    buf = replay_add(buf, _transitions(0, 3))
    assert int(buf.size) == 3 and int(buf.position) == 3
    buf = replay_add(buf, _transitions(3, 4))  # 7 written into 5 slots: 0 and 1 are gone
    assert int(buf.size) == 5 and int(buf.position) == 2
    assert sorted(np.asarray(buf.data.reward).tolist()) == [2, 3, 4, 5, 6]
    sample = replay_sample(buf, jax.random.PRNGKey(0), 1000)
    assert set(np.asarray(sample.reward).tolist()) == {2, 3, 4, 5, 6}
    np.testing.assert_array_equal(sample.next_obs[:, 0], sample.reward + 1)  # rows stay aligned


def _two_env_trajectories(steps=6):
    """Two environments' steps, written per vectorised step as the trainer does: env 0's
    episodes end (time limit) after steps 2 and 5, env 1's step 1 is terminal. Observations
    are unique; an episode's last next_obs is a final observation no later step starts from."""
    rows = []
    for t in range(steps):
        for e in range(2):
            ends = (e == 0 and t % 3 == 2) or (e == 1 and t == 1)
            obs = 1000.0 * e + 10.0 * t
            rows.append(
                dict(
                    obs=obs,
                    reward=1.0 + 0.5 * e + t,
                    next_obs=obs + 5.0 if ends else obs + 10.0,
                    terminal=float(e == 1 and t == 1),
                    ends=ends,
                )
            )
    return rows


def test_nstep_samples_sum_discounted_rewards_within_an_episode():
    """n = 3 from a wrapped ring of 2 envs x 6 steps in 9 slots: every draw starts at a slot
    whose two later steps are written, and its reward, next_obs, terminal and discount are the
    truncated n-step return of a walk along that env's episode."""
    rows, gamma, n = _two_env_trajectories(), 0.9, 3
    batch = Transition(
        obs=jnp.array([[r["obs"]] for r in rows]),
        action=jnp.zeros((len(rows), 2, 1)),
        reward=jnp.array([r["reward"] for r in rows]),
        next_obs=jnp.array([[r["next_obs"]] for r in rows]),
        terminal=jnp.array([r["terminal"] for r in rows]),
        active=jnp.ones((len(rows), 2), bool),
    )
    buf = replay_init(jax.tree.map(lambda x: x[0], batch), capacity=9)
    for t in range(6):
        buf = replay_add(buf, jax.tree.map(lambda x, t=t: x[2 * t : 2 * t + 2], batch))
    sample = replay_sample_nstep(buf, jax.random.PRNGKey(0), 400, n, 2, jnp.float32(gamma))
    by_obs = {r["obs"]: i for i, r in enumerate(rows)}
    starts = set()
    for obs, rew, nxt, term, disc in zip(
        *(np.asarray(x).reshape(400, -1)[:, 0] for x in (sample.obs, sample.reward)),
        *(np.asarray(x).reshape(400, -1)[:, 0] for x in (sample.next_obs, sample.terminal)),
        np.asarray(sample.discount),
        strict=True,
    ):
        i = by_obs[float(obs)]
        starts.add(i)
        want, m = rows[i]["reward"], 1
        while m < n and not rows[i + 2 * (m - 1)]["ends"]:
            want += gamma**m * rows[i + 2 * m]["reward"]
            m += 1
        last = rows[i + 2 * (m - 1)]
        np.testing.assert_allclose(
            [rew, nxt, term, disc],
            [want, last["next_obs"], last["terminal"], gamma ** (m - 1)],
            rtol=1e-6,
        )
    # slots hold transitions 3..11; starts 3..7 have both later steps written
    assert starts == {3, 4, 5, 6, 7}
    one = replay_sample_nstep(buf, jax.random.PRNGKey(1), 50, 1, 2, jnp.float32(gamma))
    ref = replay_sample(buf, jax.random.PRNGKey(1), 50)
    jax.tree.map(np.testing.assert_array_equal, one, ref)
    assert one.discount is None
    np.testing.assert_array_equal(continuation(one), 1.0 - one.terminal)
    np.testing.assert_allclose(continuation(sample), sample.discount * (1.0 - sample.terminal))


def test_auto_reset_restarts_episodes_and_reports_final_obs():
    env = AutoReset(envs.make("probe", episode_length=3))
    state = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    a = jnp.zeros((3, 3))
    dones = []
    for _t in range(7):
        prev_t = int(state.t)
        state = step(state, a)
        final_obs = state.info["final_obs"]
        dones.append(float(state.done))
        if state.done:
            assert int(state.t) == 0 and prev_t == 2  # a fresh episode started
        else:
            np.testing.assert_array_equal(final_obs, state.obs)
    assert dones == [0, 0, 1, 0, 0, 1, 0]


def test_agents_to_env_action_keeps_uncontrolled_at_default():
    env = envs.make("probe")
    agent_action = jnp.full((2, 5), 0.5)  # width 5 > max_dim 3
    out = agents_to_env_action(env.space, agent_action, [2, 0])
    np.testing.assert_allclose(out[1], env.space.default_action()[1])
    np.testing.assert_allclose(out[0], [0.5, 0.5, 0.5])
    np.testing.assert_allclose(out[2], [0.5, 0.5, 0.5])
    a = sample_agent_actions(env.space, [2, 0], jax.random.PRNGKey(0), (100,), 5)
    assert a.shape == (100, 2, 5)
    assert bool(jnp.all(a[:, 0, 1:] == 0)) and bool(
        jnp.all(a[:, 1, 2:] == 0)
    )  # agent 0 is 'c' (1 dim), agent 1 is 'a' (2 dims)


def test_evaluate_best_policy_and_failures():
    env = envs.make("probe", episode_length=5)
    best = lambda state, key: jax.vmap(env.best_action)(state.obs)
    ev = jax.jit(
        lambda n_failed, mode: evaluate(
            env, best, jax.random.PRNGKey(1), 8, np.arange(3), n_failed, mode
        )
    )
    r0 = ev(0, int(FailureMode.DEFAULT))
    np.testing.assert_allclose(r0.returns, 5.0, atol=1e-5)
    np.testing.assert_array_equal(r0.lengths, 5)
    r2 = ev(2, int(FailureMode.DEFAULT))
    assert float(r2.returns.mean()) < 5.0 - 1e-3  # failures cost reward
    # a policy equal to the defaults is unaffected by DEFAULT failures
    default = default_act_fn(env.space, np.arange(3), 3)
    d0, d2 = (
        (
            ev_d := jax.jit(
                lambda n: evaluate(env, default, jax.random.PRNGKey(1), 8, np.arange(3), n, 0)
            )
        )(0),
        ev_d(2),
    )
    np.testing.assert_allclose(d0.returns, d2.returns, atol=1e-5)
