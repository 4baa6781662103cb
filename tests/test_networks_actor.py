"""Actors: tanh-Gaussian + straight-through Gumbel-softmax sampling, log-probs, stacking."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.core.spaces import CompositeSpace, SubSpace
from score_jax.networks import ActorConfig, ActorOutput, Actors, grow_agents, sample_actions

# continuous 2-dim, discrete 1-dim (5 choices), discrete 2-dim (3 choices), continuous 1-dim
SPACE = CompositeSpace(
    (
        SubSpace.continuous("u", 2, -1.0, 1.0, 0.0),
        SubSpace.discrete("k5", 1, 0.0, 4.0, 2.0, n_choices=5),
        SubSpace.discrete("k3", 2, 0.0, 2.0, 1.0, n_choices=3),
        SubSpace.continuous("v", 1, 0.0, 1.0, 0.5),
    )
)
WIDTH, OBS = 3, 6
DIM_MASK = jnp.pad(jnp.asarray(SPACE.dim_mask), ((0, 0), (0, WIDTH - SPACE.max_dim)))
N_CHOICES = jnp.pad(jnp.asarray(SPACE.n_choices), ((0, 0), (0, WIDTH - SPACE.max_dim)))
CFG = ActorConfig(hidden=(16,))


@pytest.fixture(scope="module")
def actors():
    model = Actors(
        CFG, SPACE.n, WIDTH, SPACE.max_choices, discrete_width=2
    )  # logits only for the first 2 columns
    params = jax.jit(model.init)(jax.random.PRNGKey(0), jnp.zeros(OBS))["params"]
    return model, params


@pytest.fixture(scope="module")
def samples(actors):
    model, params = actors
    out = model.apply({"params": params}, jnp.linspace(-1, 1, OBS))
    keys = jax.random.split(jax.random.PRNGKey(1), 2000)
    acts, logps = jax.jit(jax.vmap(lambda k: sample_actions(out, DIM_MASK, N_CHOICES, k)))(keys)
    return out, np.asarray(acts), np.asarray(logps)


def test_shapes_and_stacked_params(actors):
    model, params = actors
    out = model.apply({"params": params}, jnp.ones(OBS))
    assert out.mean.shape == (SPACE.n, WIDTH) and out.log_std.shape == (SPACE.n, WIDTH)
    assert out.logits.shape == (SPACE.n, 2, SPACE.max_choices)
    assert np.all(out.log_std >= CFG.log_std_min) and np.all(out.log_std <= CFG.log_std_max)
    assert all(x.shape[0] == SPACE.n for x in jax.tree_util.tree_leaves(params))
    # independent actors: different params per agent give different outputs
    assert not np.allclose(out.mean[0], out.mean[3])


def test_actions_valid_padded_zero_discrete_on_grid(samples):
    _, acts, logps = samples
    assert acts.shape == (2000, SPACE.n, WIDTH) and logps.shape == (2000, SPACE.n)
    assert np.all(np.abs(acts) <= 1.0) and np.all(np.isfinite(logps))
    assert np.all(acts[:, ~np.asarray(DIM_MASK)] == 0.0)
    grid5, grid3 = np.array([-1, -0.5, 0, 0.5, 1], np.float32), np.array([-1, 0, 1], np.float32)
    assert np.all(np.isin(acts[:, 1, 0], grid5)) and np.all(np.isin(acts[:, 2, :2], grid3))
    # the space's own conversion agrees the values are grid values
    a = jnp.asarray(acts[:, :, : SPACE.max_dim])
    np.testing.assert_array_equal(SPACE.choice_value(SPACE.choice_index(a))[:, 1:3], a[:, 1:3])
    # continuous dims are continuous
    assert len(np.unique(acts[:, 0, 0])) > 1900


def test_discrete_sampling_frequencies_match_softmax(samples):
    out, acts, _ = samples
    probs = np.asarray(jax.nn.softmax(out.logits[1, 0, :5]))
    idx = np.round((acts[:, 1, 0] + 1) / 2 * 4).astype(int)
    freq = np.bincount(idx, minlength=5) / len(idx)
    np.testing.assert_allclose(freq, probs, atol=0.04)
    # choices beyond n_choices never appear (k3 has 3 of the 5 logits)
    idx3 = np.round((acts[:, 2, :2] + 1) / 2 * 2).astype(int)
    assert idx3.max() <= 2


def test_log_prob_matches_hand_computation():
    # one agent, column 0 continuous, column 1 discrete with 4 choices, column 2 padded
    mean, log_std = 0.3, -0.7
    logits = jnp.array([0.2, -1.0, 1.5, 0.1, 9.0])  # the 5th choice is invalid (n_choices = 4)
    out = ActorOutput(
        mean=jnp.array([[mean, 5.0, 5.0]]),
        log_std=jnp.array([[log_std, 1.0, 1.0]]),
        logits=jnp.stack([jnp.zeros(5), logits, jnp.zeros(5)])[None],
    )
    dim_mask = jnp.array([[True, True, False]])
    n_choices = jnp.array([[0, 4, 0]])
    for seed in range(5):
        action, logp = sample_actions(out, dim_mask, n_choices, jax.random.PRNGKey(seed))
        a = float(action[0, 0])
        u = math.atanh(a)
        std = math.exp(log_std)
        normal = -0.5 * ((u - mean) / std) ** 2 - log_std - 0.5 * math.log(2 * math.pi)
        cont = normal - math.log(1 - a * a)
        k = round((float(action[0, 1]) + 1) / 2 * 3)
        # exactly the grid value, computed in float32 as CompositeSpace.choice_value does
        assert action[0, 1] == np.float32(k) / np.float32(3) * np.float32(2) - np.float32(1)
        assert k < 4 and action[0, 2] == 0.0
        lp = np.asarray(jax.nn.log_softmax(logits[:4]))
        disc = float(
            np.sum(np.exp(lp) * lp)
        )  # exact expectation: minus the entropy of the 4 valid choices
        np.testing.assert_allclose(float(logp[0]), cont + disc, rtol=2e-4, atol=2e-4)


def test_discrete_entropy_bonus_has_a_gradient():
    """The expected -log p of a discrete dim is its entropy, so an entropy bonus moves the logits
    towards uniform (with a sampled log p(k) the expected gradient would be zero)."""
    logits = jnp.array([[[2.0, 0.0, -1.0]]])
    out = lambda lg: ActorOutput(mean=jnp.zeros((1, 1)), log_std=jnp.zeros((1, 1)), logits=lg)
    neg_entropy = lambda lg: sample_actions(
        out(lg), jnp.array([[True]]), jnp.array([[3]]), jax.random.PRNGKey(0)
    )[1][0]
    g = jax.grad(neg_entropy)(logits)
    stepped = logits - 0.5 * g
    assert float(neg_entropy(stepped)) < float(neg_entropy(logits))


def test_deterministic_mode():
    out = ActorOutput(
        mean=jnp.array([[0.4, 0.0]]),
        log_std=jnp.zeros((1, 2)),
        logits=jnp.array([[[0.0, 0.0, 0.0], [0.1, 2.0, 3.0]]]),  # the 3.0 is invalid (n_choices 2)
    )
    dim_mask, n_choices = jnp.array([[True, True]]), jnp.array([[0, 2]])
    a1, lp1 = sample_actions(out, dim_mask, n_choices, jax.random.PRNGKey(0), deterministic=True)
    a2, lp2 = sample_actions(out, dim_mask, n_choices, jax.random.PRNGKey(1), deterministic=True)
    assert np.array_equal(a1, a2) and np.array_equal(lp1, lp2)
    np.testing.assert_allclose(a1[0, 0], np.tanh(0.4), rtol=1e-6)
    assert a1[0, 1] == 1.0  # argmax over the 2 valid choices -> grid value +1


def test_gradients_flow_through_both_kinds(actors):
    model, params = actors
    obs = jnp.linspace(-1, 1, OBS)
    weights = jax.random.normal(jax.random.PRNGKey(3), (SPACE.n, WIDTH))

    def objective(p, key):
        a, logp = sample_actions(model.apply({"params": p}, obs), DIM_MASK, N_CHOICES, key)
        return jnp.sum(a * weights), jnp.sum(logp)

    key = jax.random.PRNGKey(4)
    both = jax.jit(
        lambda p: (
            jax.grad(lambda q: objective(q, key)[0])(p),
            jax.grad(lambda q: objective(q, key)[1])(p),
        )
    )
    g_val, g_logp = both(params)
    out_kernel = lambda g: np.asarray(
        g["agents"]["mlp"]["out"]["kernel"]
    )  # [n, hidden, width * (2 + C)]
    # Value gradients reach every agent: continuous ones via mean, discrete via logits.
    for i in range(SPACE.n):
        assert np.any(out_kernel(g_val)[i] != 0), f"no action gradient for agent {i}"
        assert np.any(out_kernel(g_logp)[i] != 0), f"no log-prob gradient for agent {i}"
    C = SPACE.max_choices
    logits_cols = out_kernel(g_val)[1][:, 2 * WIDTH : 2 * WIDTH + C]  # agent k5, column 0 logits
    assert np.any(logits_cols != 0)
    # A padded column's heads get no gradient from the action value.
    mean_col_pad = out_kernel(g_val)[0][:, 2]  # agent u, column 2 (padded) mean
    assert np.all(mean_col_pad == 0)


def test_grow_agents(actors):
    model, params = actors
    extra = jax.jit(Actors(CFG, 2, WIDTH, SPACE.max_choices, discrete_width=2).init)(
        jax.random.PRNGKey(9), jnp.zeros(OBS)
    )["params"]
    grown = grow_agents(params, extra)
    assert all(x.shape[0] == SPACE.n + 2 for x in jax.tree_util.tree_leaves(grown))
    big = Actors(CFG, SPACE.n + 2, WIDTH, SPACE.max_choices, discrete_width=2)
    obs = jnp.ones(OBS)
    out_big, out_old = (
        jax.jit(big.apply)({"params": grown}, obs),
        model.apply({"params": params}, obs),
    )
    np.testing.assert_allclose(out_big.mean[: SPACE.n], out_old.mean, rtol=1e-6)
    np.testing.assert_allclose(out_big.logits[: SPACE.n], out_old.logits, rtol=1e-6)
    with pytest.raises(ValueError, match="differ in shape"):
        wider = jax.eval_shape(
            Actors(CFG, 1, WIDTH + 1, SPACE.max_choices).init, jax.random.PRNGKey(9), jnp.zeros(OBS)
        )["params"]
        grow_agents(params, jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), wider))


def test_fresh_actor_plays_the_default_and_explores_around_it(actors):
    """The default is the actors' prior: a fresh (near-zero output) actor's deterministic
    action is the default of every sub-space, discrete dims included, and stochastic
    samples pick a discrete default with probability e^b / (e^b + C - 1)."""
    model, params = actors
    default = jnp.pad(jnp.asarray(SPACE.default_action()), ((0, 0), (0, WIDTH - SPACE.max_dim)))
    out = model.apply({"params": params}, jnp.linspace(-1, 1, OBS))
    det, _ = sample_actions(
        out, DIM_MASK, N_CHOICES, jax.random.PRNGKey(0), True, 1.0, default, 3.0
    )
    np.testing.assert_allclose(det, default, atol=0.05)  # continuous: tanh(mean + atanh(default))
    real_discrete = np.asarray(DIM_MASK & (N_CHOICES > 0))
    np.testing.assert_array_equal(
        np.asarray(det)[real_discrete], np.asarray(default)[real_discrete]
    )
    keys = jax.random.split(jax.random.PRNGKey(2), 4000)
    acts, _ = jax.jit(
        jax.vmap(lambda k: sample_actions(out, DIM_MASK, N_CHOICES, k, False, 1.0, default, 3.0))
    )(keys)
    hit = np.mean(np.asarray(acts)[:, 1, 0] == np.asarray(default)[1, 0])  # k5: 5 choices
    assert abs(hit - math.e**3 / (math.e**3 + 4)) < 0.05
    # without the prior the same actor is near uniform over the 5 choices
    acts0, _ = jax.jit(jax.vmap(lambda k: sample_actions(out, DIM_MASK, N_CHOICES, k)))(keys)
    assert abs(np.mean(np.asarray(acts0)[:, 1, 0] == np.asarray(default)[1, 0]) - 0.2) < 0.05
