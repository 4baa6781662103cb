"""The shared SAC losses (Alg. 1 lines 12-14) against hand computation on a tiny case."""

import jax
import jax.numpy as jnp
import numpy as np
import optax

from score_jax.agents.base import AgentConsts, target_entropy
from score_jax.agents.replay import Transition
from score_jax.agents.sac.losses import actor_loss, alpha_loss, critic_loss, pessimistic_q
from score_jax.agents.sac.state import SACHyper, SACState
from score_jax.agents.sac.update import make_sac_update

OBS = np.array([[0.5], [-1.0]], np.float32)
NEXT = np.array([[1.0], [0.25]], np.float32)
REWARD = np.array([1.0, -2.0], np.float32)
TERMINAL = np.array([0.0, 1.0], np.float32)
ACTION = np.array([[[0.3], [-0.2]], [[0.1], [0.9]]], np.float32)
MASK = np.array([[True, True], [True, False]])
GAMMA, ALPHA = 0.9, 0.2


def policy_fn(actor, consts, obs, key, deterministic):
    a = jnp.tanh(actor["w"] * obs)[:, None, :] * jnp.array([1.0, -1.0])[None, :, None]  # [B, 2, 1]
    return a, -0.5 * a[..., 0] ** 2 - 1.0  # log-probs [B, 2]


def q_fn(critic, consts, obs, action, mask):
    s = jnp.sum(jnp.where(mask, action[..., 0], 0.0), axis=-1)  # [B]
    return critic["a"][None, :] * s[:, None] + critic["b"][None, :] * obs  # [B, 2]


def _state():
    consts = AgentConsts(
        jnp.ones((2, 1), bool),
        jnp.zeros((2, 1), jnp.int32),
        jnp.ones(2, bool),
        jnp.array([-1.0, -1.0]),
    )
    critic = {"a": jnp.array([1.0, 2.0]), "b": jnp.array([0.5, -0.5])}
    target = {"a": jnp.array([0.8, 1.5]), "b": jnp.array([0.2, 0.1])}
    return SACState(
        actor={"w": jnp.array(0.7)},
        critic=critic,
        target_critic=target,
        log_alpha=jnp.log(ALPHA),
        actor_opt=None,
        critic_opt=None,
        alpha_opt=None,
        consts=consts,
    )


def _np_policy(w, obs):
    a = np.tanh(w * obs[:, 0])[:, None] * np.array([1.0, -1.0])
    return a, -0.5 * a**2 - 1.0


def test_critic_loss_by_hand():
    state = _state()
    batch = Transition(OBS, ACTION, REWARD, NEXT, TERMINAL, np.ones((2, 2), bool))
    hyper = SACHyper(jnp.float32(GAMMA), jnp.float32(0.005), jnp.float32(0.0), jnp.float32(1.0))
    loss, _ = critic_loss(
        state.critic, state, batch, MASK, jax.random.PRNGKey(0), hyper, policy_fn, q_fn
    )
    a_next, logp_next = _np_policy(0.7, NEXT)
    s_next = np.sum(np.where(MASK, a_next, 0), -1)
    q_next = np.minimum(0.8 * s_next + 0.2 * NEXT[:, 0], 1.5 * s_next + 0.1 * NEXT[:, 0])
    y = REWARD + GAMMA * (1 - TERMINAL) * (
        q_next - ALPHA * np.sum(np.where(MASK, logp_next, 0), -1)
    )
    s = np.sum(np.where(MASK, ACTION[..., 0], 0), -1)
    q = np.stack([1.0 * s + 0.5 * OBS[:, 0], 2.0 * s - 0.5 * OBS[:, 0]], -1)
    expected = 0.5 * np.mean(np.sum((q - y[:, None]) ** 2, -1))
    np.testing.assert_allclose(float(loss), expected, rtol=1e-5)


def test_pessimism_moves_from_the_twins_min_to_their_mean():
    q = jax.random.normal(jax.random.PRNGKey(3), (64, 2, 3)) * 100.0  # [B, k=2, n]
    # beta = 1 is clipped double Q bit for bit, so the default reproduces earlier runs exactly
    np.testing.assert_array_equal(pessimistic_q(q, 1.0), jnp.min(q, axis=1))
    np.testing.assert_allclose(pessimistic_q(q, 0.0), jnp.mean(q, axis=1), rtol=1e-5, atol=1e-4)
    gap = jnp.abs(q[:, 0] - q[:, 1])
    np.testing.assert_allclose(
        pessimistic_q(q, 0.25), jnp.mean(q, axis=1) - 0.25 * gap / 2, rtol=1e-5, atol=1e-4
    )
    one = q[:, :1]  # a single critic (k = 1) is its own estimate at any beta
    np.testing.assert_array_equal(pessimistic_q(one, 0.3), one[:, 0])


def test_critic_and_actor_losses_with_the_twins_mean():
    state = _state()
    batch = Transition(OBS, ACTION, REWARD, NEXT, TERMINAL, np.ones((2, 2), bool))
    hyper = SACHyper(
        jnp.float32(GAMMA), jnp.float32(0.005), jnp.float32(0.0), jnp.float32(1.0), jnp.float32(0.0)
    )
    loss, _ = critic_loss(
        state.critic, state, batch, MASK, jax.random.PRNGKey(0), hyper, policy_fn, q_fn
    )
    a_next, logp_next = _np_policy(0.7, NEXT)
    s_next = np.sum(np.where(MASK, a_next, 0), -1)
    q_next = 0.5 * (0.8 * s_next + 0.2 * NEXT[:, 0] + 1.5 * s_next + 0.1 * NEXT[:, 0])
    y = REWARD + GAMMA * (1 - TERMINAL) * (
        q_next - ALPHA * np.sum(np.where(MASK, logp_next, 0), -1)
    )
    s = np.sum(np.where(MASK, ACTION[..., 0], 0), -1)
    q = np.stack([1.0 * s + 0.5 * OBS[:, 0], 2.0 * s - 0.5 * OBS[:, 0]], -1)
    np.testing.assert_allclose(
        float(loss), 0.5 * np.mean(np.sum((q - y[:, None]) ** 2, -1)), rtol=1e-5
    )
    a_loss, _ = actor_loss(
        state.actor, state, batch, MASK, jax.random.PRNGKey(0), policy_fn, q_fn, pessimism=0.0
    )
    a, logp = _np_policy(0.7, OBS)
    s = np.sum(np.where(MASK, a, 0), -1)
    q_mean = 0.5 * (1.0 * s + 0.5 * OBS[:, 0] + 2.0 * s - 0.5 * OBS[:, 0])
    slp = np.sum(np.where(MASK, logp, 0), -1)
    np.testing.assert_allclose(float(a_loss), np.mean(ALPHA * slp - q_mean), rtol=1e-5)


def test_actor_and_alpha_loss_by_hand():
    state = _state()
    batch = Transition(OBS, ACTION, REWARD, NEXT, TERMINAL, np.ones((2, 2), bool))
    loss, logp_agents = actor_loss(
        state.actor, state, batch, MASK, jax.random.PRNGKey(0), policy_fn, q_fn
    )
    a, logp = _np_policy(0.7, OBS)
    s = np.sum(np.where(MASK, a, 0), -1)
    q = np.minimum(1.0 * s + 0.5 * OBS[:, 0], 2.0 * s - 0.5 * OBS[:, 0])
    slp = np.sum(np.where(MASK, logp, 0), -1)
    np.testing.assert_allclose(float(loss), np.mean(ALPHA * slp - q), rtol=1e-5)
    np.testing.assert_allclose(logp_agents, logp, rtol=1e-6)
    # shared alpha: -mean(log_alpha * (sum_logp + masked target)); targets are -1 per active agent
    al = alpha_loss(jnp.log(ALPHA), logp_agents, MASK, state.consts)
    np.testing.assert_allclose(
        float(al), -np.mean(np.log(ALPHA) * (slp + np.array([-2.0, -1.0]))), rtol=1e-5
    )
    # one temperature per agent: each agent's term only moves its own alpha
    log_alphas = jnp.log(jnp.array([0.2, 0.5]))
    grad = jax.grad(alpha_loss)(log_alphas, logp_agents, MASK, state.consts)
    expected = -np.sum(np.where(MASK, logp + (-1.0), 0.0), axis=0) / 2
    np.testing.assert_allclose(grad, expected, rtol=1e-5)
    # per-agent actor loss weights each agent's log-prob by its own alpha
    per_agent = actor_loss(
        state.actor,
        state.replace(log_alpha=log_alphas),
        batch,
        MASK,
        jax.random.PRNGKey(0),
        policy_fn,
        q_fn,
    )[0]
    np.testing.assert_allclose(
        float(per_agent),
        np.mean(np.sum(np.where(MASK, np.array([0.2, 0.5]) * logp, 0), -1) - q),
        rtol=1e-5,
    )


def test_target_entropy_counts_valid_dims():
    dim_mask = jnp.array([[True, True, False], [True, False, False]])
    n_choices = jnp.array([[0, 0, 0], [24, 0, 0]])
    np.testing.assert_allclose(
        target_entropy(dim_mask, n_choices, 0.5), [-2.0, 0.5 * np.log(24)], rtol=1e-6
    )


def test_update_moves_critic_towards_target_and_polyak_averages():
    state = _state()
    opt = optax.sgd(0.05)
    state = state.replace(
        actor_opt=opt.init(state.actor),
        critic_opt=opt.init(state.critic),
        alpha_opt=opt.init(state.log_alpha),
    )
    update = jax.jit(make_sac_update(policy_fn, q_fn, opt, opt, opt))
    batch = Transition(OBS, ACTION, REWARD, NEXT, TERMINAL, np.ones((2, 2), bool))
    hyper = SACHyper(jnp.float32(GAMMA), jnp.float32(0.1), jnp.float32(0.0), jnp.float32(1.0))
    loss_before, _ = critic_loss(
        state.critic,
        state,
        batch,
        jnp.ones((2, 2), bool),
        jax.random.PRNGKey(0),
        hyper,
        policy_fn,
        q_fn,
    )
    new, metrics = update(state, batch, jax.random.PRNGKey(0), hyper)
    loss_after, _ = critic_loss(
        new.critic,
        new.replace(target_critic=state.target_critic),
        batch,
        jnp.ones((2, 2), bool),
        jax.random.PRNGKey(0),
        hyper,
        policy_fn,
        q_fn,
    )
    assert float(loss_after) < float(loss_before)
    np.testing.assert_allclose(float(metrics["critic_loss"]), float(loss_before), rtol=1e-5)
    expected_target = jax.tree.map(lambda c, t: 0.1 * c + 0.9 * t, new.critic, state.target_critic)
    jax.tree.map(
        lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6), new.target_critic, expected_target
    )


def test_actor_step_uses_the_critics_the_update_starts_from():
    # Both agents act tanh(w o) here, so Q's action term reaches the actor (the policy above
    # cancels it).
    def same_sign(actor, consts, obs, key, det):
        action, logp = policy_fn(actor, consts, obs, key, det)
        return jnp.abs(action), logp

    state = _state()
    opt = optax.sgd(0.05)
    state = state.replace(
        actor_opt=opt.init(state.actor),
        critic_opt=opt.init(state.critic),
        alpha_opt=opt.init(state.log_alpha),
    )
    batch = Transition(OBS, ACTION, REWARD, NEXT, TERMINAL, np.ones((2, 2), bool))
    hyper = SACHyper(jnp.float32(GAMMA), jnp.float32(0.1), jnp.float32(0.0), jnp.float32(1.0))
    new, _ = jax.jit(make_sac_update(same_sign, q_fn, opt, opt, opt))(
        state, batch, jax.random.PRNGKey(0), hyper
    )
    key_actor = jax.random.split(jax.random.PRNGKey(0), 3)[2]
    step = lambda st: float(
        state.actor["w"]
        - 0.05
        * jax.grad(
            lambda a: actor_loss(a, st, batch, jnp.ones((2, 2), bool), key_actor, same_sign, q_fn)[
                0
            ]
        )(state.actor)["w"]
    )
    np.testing.assert_allclose(float(new.actor["w"]), step(state), rtol=1e-6)
    assert (
        abs(step(state.replace(critic=new.critic)) - step(state)) > 1e-5
    )  # the test can tell the two orders apart
