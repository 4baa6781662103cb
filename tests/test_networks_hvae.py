"""HVAE + ASRL (§4.1): data collection, the ELBO falls, embeddings tell sub-spaces apart,
unseen sub-spaces can be embedded by the frozen encoder (§4.3)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from score_jax.agents.score.asrl import collect_observation_sets, embed_new_spaces, train_hvae
from score_jax.networks import HVAE, HVAEConfig
from score_jax.networks.hvae import init_hvae, observation_set_shapes

WIDTH = 4  # wider than the probe's max_dim (3): the transfer convention
CFG = HVAEConfig(obs_embed_dim=16, space_embed_dim=8, latent_dim=8, hidden=32, predict_steps=2)
K, J, WARMUP, STEPS = 16, 4, 3, 1500


@pytest.fixture(scope="module")
def probe():
    return envs.make("probe")


@pytest.fixture(scope="module")
def trained(probe):
    """HVAE trained on sub-spaces a, b of the probe; c is held at its default (a subset run)."""
    fixed = jnp.array([False, False, True])
    return train_hvae(
        probe,
        jax.random.PRNGKey(1),
        CFG,
        [0, 1],
        K,
        J,
        STEPS,
        WIDTH,
        fixed_default=fixed,
        warmup_steps=WARMUP,
    )


def test_collect_observation_sets_layout(probe):
    fixed = jnp.array([False, False, True])
    sets = collect_observation_sets(
        probe,
        jax.random.PRNGKey(0),
        [0, 1],
        3,
        5,
        2,
        WIDTH,
        warmup_steps=WARMUP,
        fixed_default=fixed,
    )
    assert sets.obs.shape == (2, 15, 4) and sets.prev_obs.shape == (2, 15, 4)
    assert sets.actions.shape == (2, 15, WIDTH) and sets.future.shape == (2, 15, 2, 4)
    np.testing.assert_array_equal(sets.dim_mask, [[1, 1, 0, 0], [1, 1, 1, 0]])
    assert np.all(
        np.asarray(sets.actions)[
            ~np.broadcast_to(np.asarray(sets.dim_mask)[:, None], sets.actions.shape)
        ]
        == 0
    )
    assert (
        np.all(np.abs(sets.actions) <= 1)
        and bool(sets.future_mask.all())
        and bool(sets.set_mask.all())
    )
    np.testing.assert_array_equal(sets.group[0], np.repeat(np.arange(3), 5))
    # The j sub-actions of one fixing start from one state and differ from each other.
    prev = np.asarray(sets.prev_obs).reshape(2, 3, 5, 4)
    assert np.all(prev == prev[:, :, :1]) and not np.allclose(prev[:, 0, 0], prev[:, 1, 0])
    acts = np.asarray(sets.actions).reshape(2, 3, 5, WIDTH)
    assert len(np.unique(acts[0, 0, :, 0])) == 5
    # Deterministic under a seed.
    again = collect_observation_sets(
        probe,
        jax.random.PRNGKey(0),
        [0, 1],
        3,
        5,
        2,
        WIDTH,
        warmup_steps=WARMUP,
        fixed_default=fixed,
    )
    assert np.array_equal(again.obs, sets.obs) and np.array_equal(again.actions, sets.actions)
    with pytest.raises(ValueError, match="action_width"):
        collect_observation_sets(probe, jax.random.PRNGKey(0), [0], 1, 1, 1, 2)
    with pytest.raises(ValueError, match="agents"):
        collect_observation_sets(probe, jax.random.PRNGKey(0), [3], 1, 1, 1, WIDTH)


def test_observation_set_shapes_are_the_collectors(probe):
    """``observation_set_shapes`` (what a restore builds the HVAE's template from, without
    tracing the environment) is exactly what the collector returns, and so is the HVAE
    initialised on it."""
    collect = lambda key: collect_observation_sets(
        probe, key, [0, 2], 3, 5, 2, WIDTH, warmup_steps=WARMUP
    )
    real = jax.eval_shape(collect, jax.random.PRNGKey(0))
    shapes = observation_set_shapes(probe.observation_size, 2, 3, 5, 2, WIDTH)
    assert jax.tree.structure(real) == jax.tree.structure(shapes)
    for a, b in zip(jax.tree.leaves(real), jax.tree.leaves(shapes), strict=True):
        assert (a.shape, a.dtype) == (b.shape, b.dtype)
    model = HVAE(CFG, probe.observation_size, WIDTH)
    init = lambda sets: jax.eval_shape(
        lambda k, s: init_hvae(model, k, s), jax.random.PRNGKey(0), sets
    )
    assert jax.tree.map(lambda x: (x.shape, x.dtype), init(real)) == jax.tree.map(
        lambda x: (x.shape, x.dtype), init(shapes)
    )


def test_elbo_falls_on_probe(trained):
    elbo = trained.elbo_history
    assert elbo.shape == (STEPS,) and np.all(np.isfinite(elbo))
    first, last = elbo[:20].mean(), elbo[-20:].mean()
    print(f"probe ELBO per observation {first:.2f} -> {last:.2f}")
    assert last > first + 5.0, f"ELBO per observation {first:.2f} -> {last:.2f}"
    m = trained.metrics
    # the logged ELBO is eq. 2's alone; the action-reconstruction term is its own metric
    eq2 = -(float(m.recon) + float(m.pred) + float(m.kl_z) + float(m.kl_c))
    assert float(m.elbo) == pytest.approx(eq2, rel=1e-5, abs=1e-4)
    assert np.isfinite(float(m.act)) and float(m.act) != 0.0
    assert float(m.kl_z) > 1.0, (
        "the latent sub-action z carries information (no posterior collapse)"
    )


def test_embeddings_distinguish_sub_spaces(probe, trained):
    c = np.asarray(trained.c)
    assert c.shape == (2, CFG.space_embed_dim) and np.all(np.isfinite(c))
    fixed = jnp.array([False, False, True])
    c_again = np.asarray(
        embed_new_spaces(
            probe,
            trained.model,
            trained.params,
            jax.random.PRNGKey(11),
            [0, 1],
            K,
            J,
            WARMUP,
            fixed,
        )
    )
    within = np.linalg.norm(c - c_again, axis=-1)  # same sub-space, independent sets
    between = np.linalg.norm(c[0] - c[1])
    print(f"between {between:.3f}, within {within}")
    assert between > 3.0 * within.max(), f"between {between:.3f} vs within {within}"


def test_unseen_sub_space_is_embedded(probe, trained):
    fixed = jnp.array([False, False, True])
    c_new = np.asarray(
        embed_new_spaces(
            probe, trained.model, trained.params, jax.random.PRNGKey(12), [2], K, J, WARMUP, fixed
        )
    )
    c_new2 = np.asarray(
        embed_new_spaces(
            probe, trained.model, trained.params, jax.random.PRNGKey(13), [2], K, J, WARMUP, fixed
        )
    )
    assert c_new.shape == (1, CFG.space_embed_dim) and np.all(np.isfinite(c_new))
    within = np.linalg.norm(c_new - c_new2)
    to_seen = np.linalg.norm(np.asarray(trained.c) - c_new, axis=-1)
    print(f"unseen->seen {to_seen}, unseen within {within:.3f}")
    assert to_seen.min() > 1.5 * within, f"unseen vs seen {to_seen} vs within {within:.3f}"
    # ... and the frozen action encoder takes it: finite, action-dependent latents.
    model, params = trained.model, trained.params
    dm = jnp.array([True, False, False, False])
    z = lambda a: model.apply(
        {"params": params},
        jnp.zeros(4),
        jnp.array([a, 0, 0, 0.0]),
        dm,
        c_new[0],
        method=HVAE.encode_action,
    )[0]
    assert np.all(np.isfinite(z(0.5))) and not np.allclose(z(-1.0), z(1.0), atol=1e-3)


@pytest.mark.slow
def test_elbo_falls_on_greenhouse():
    try:
        env = envs.make("greenhouse")
    except (ImportError, ModuleNotFoundError) as err:  # the environment is built in parallel
        pytest.skip(f"greenhouse environment not available yet: {err}")
    cfg = HVAEConfig(obs_embed_dim=16, space_embed_dim=4, latent_dim=8, hidden=32, predict_steps=2)
    width = env.space.max_dim
    res = train_hvae(
        env, jax.random.PRNGKey(0), cfg, range(env.space.n), 4, 4, 150, width, warmup_steps=20
    )
    elbo = res.elbo_history
    assert np.all(np.isfinite(elbo)) and res.c.shape == (env.space.n, 4)
    print(f"greenhouse ELBO per observation {elbo[:10].mean():.1f} -> {elbo[-10:].mean():.1f}")
    assert elbo[-10:].mean() > elbo[:10].mean() + 100.0, (
        f"{elbo[:10].mean():.1f} -> {elbo[-10:].mean():.1f}"
    )


def test_code_contrast_separates_sets():
    """InfoNCE over the sets' halves: log S when codes coincide, ~0 when each set's halves are
    far from the others', 0 for one set; its gradient pushes different sets' codes apart."""
    from score_jax.networks.hvae import code_contrast

    same = jnp.zeros((4, 3))
    assert float(code_contrast(same, same, 1.0)) == pytest.approx(np.log(4.0), rel=1e-6)
    apart = 10.0 * jnp.eye(4, 3)
    assert float(code_contrast(apart, apart + 0.01, 1.0)) < 1e-6
    assert float(code_contrast(jnp.ones((1, 3)), -jnp.ones((1, 3)), 1.0)) == 0.0
    close = jnp.array([[0.0, 0.0], [0.1, 0.0]])

    def spread(c):
        return code_contrast(c, c, 1.0)

    moved = close - 0.1 * jax.grad(spread)(close)
    assert float(jnp.linalg.norm(moved[0] - moved[1])) > 0.1
    assert float(spread(moved)) < float(spread(close))


def test_code_contrast_weight_enters_the_loss(probe):
    """The term is added to the loss with its weight and the ELBO is eq. 2's alone either way;
    with weight 0 it is not computed at all (0, and the loss is the plain one)."""
    from score_jax.networks.hvae import hvae_loss, init_hvae

    fixed = jnp.array([False, False, True])
    sets = collect_observation_sets(
        probe, jax.random.PRNGKey(3), [0, 1], 4, 2, CFG.predict_steps, WIDTH, WARMUP, fixed
    )
    key = jax.random.PRNGKey(4)

    def model(weight):
        cfg = HVAEConfig(**{**CFG.__dict__, "code_contrast_weight": weight})
        return HVAE(cfg, probe.observation_size, WIDTH)

    params = init_hvae(model(0.0), jax.random.PRNGKey(5), sets)
    _, m0 = hvae_loss(params, model(0.0), sets, key)
    _, m1 = hvae_loss(params, model(1.0), sets, key)
    _, m2 = hvae_loss(params, model(2.0), sets, key)
    assert 0.0 < float(m1.contrast) <= np.log(2.0) + 1e-6
    assert float(m2.contrast) == pytest.approx(float(m1.contrast), rel=1e-6)
    assert float(m2.elbo) == pytest.approx(float(m1.elbo), rel=1e-6)
    assert float(m2.loss) == pytest.approx(float(m1.loss) + float(m1.contrast), rel=1e-5)
    assert float(m0.contrast) == 0.0 and float(m0.elbo) == pytest.approx(float(m1.elbo), rel=1e-6)
    assert float(m1.loss) == pytest.approx(float(m0.loss) + float(m1.contrast), rel=1e-5)
