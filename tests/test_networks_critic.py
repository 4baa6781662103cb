"""The masked GAT and the graph critic: invariances, masking, switches, frozen HVAE."""

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.agents.score.networks import with_asrl_encoders
from score_jax.networks import (
    HVAE,
    CriticConfig,
    GATWeights,
    GraphCritic,
    HVAEConfig,
    TwinCritic,
    finetune_mask,
    flatten_gat_weights,
    gat_layer,
    gat_num_params,
    init_gat_weights,
    unflatten_gat_weights,
)
from score_jax.networks.critic import HyperNet
from score_jax.networks.mlp import MLP

OBS, WIDTH, N = 5, 4, 4
HCFG = HVAEConfig(obs_embed_dim=8, space_embed_dim=4, latent_dim=4, hidden=16, predict_steps=2)
# finetune_asrl=False: most tests here check the frozen-HVAE path (the paper's text); the
# fine-tuned encoders have their own test.
CCFG = CriticConfig(hidden=16, agent_dim=8, gat_layers=2, hyper_hidden=8, finetune_asrl=False)
DIM_MASK = jnp.array([[1, 1, 0, 0], [1, 1, 1, 0], [1, 0, 0, 0], [1, 1, 1, 1]], bool)


@pytest.fixture(scope="module")
def hvae_params():
    # The critic uses q_phi (encode_obs) and q_psi (encode_action); initialising through
    # encode_action creates exactly those parameters.
    model = HVAE(HCFG, OBS, WIDTH)
    args = (jnp.zeros(OBS), jnp.zeros(WIDTH), DIM_MASK[0], jnp.zeros(HCFG.space_embed_dim))
    init = jax.jit(lambda key: model.init(key, *args, method=HVAE.encode_action))
    return init(jax.random.PRNGKey(0))["params"]


@pytest.fixture(scope="module")
def inputs():
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(2), 3)
    obs = jax.random.uniform(k1, (OBS,), minval=-1, maxval=1)
    actions = jnp.where(DIM_MASK, jax.random.uniform(k2, (N, WIDTH), minval=-1, maxval=1), 0.0)
    c = jax.random.normal(k3, (N, HCFG.space_embed_dim))
    return obs, actions, DIM_MASK, c, jnp.ones(N, bool)


def make(cfg, hvae_params, inputs, key=3):
    critic = GraphCritic(cfg, HCFG, OBS, WIDTH)
    params = critic.init(jax.random.PRNGKey(key), *inputs, hvae_params)["params"]
    return critic, params


ALL_CONFIGS = [
    dataclasses.replace(CCFG, aggregation=agg, hypernet=hyper, asrl=asrl)
    for agg in ("attention", "mean", "sum")
    for hyper in (True, False)
    for asrl in (True, False)
] + [dataclasses.replace(CCFG, self_term=True)]


# --- gat_layer ------------------------------------------------------------------------
def test_gat_layer_matches_hand_computation():
    x = jnp.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    w = GATWeights(
        theta=jnp.array([[1.0, 2.0], [0.5, -1.0]]), attn=jnp.array([0.3, -0.2, 0.5, 0.1])
    )
    mask = jnp.array([True, True, False])
    out, alpha = gat_layer(w, x, mask, "attention")
    h = np.asarray(x) @ np.asarray(w.theta)
    score = np.array([[h[i] @ [0.3, -0.2] + h[j] @ [0.5, 0.1] for j in range(2)] for i in range(2)])
    score = np.where(score > 0, score, 0.2 * score)
    expect_alpha = np.exp(score) / np.exp(score).sum(1, keepdims=True)
    expect = expect_alpha @ h[:2]
    expect = np.where(expect > 0, expect, np.expm1(expect))  # ELU
    np.testing.assert_allclose(alpha[:2, :2], expect_alpha, rtol=1e-5)
    np.testing.assert_allclose(out[:2], expect, rtol=1e-5)
    assert np.all(np.asarray(alpha)[2] == 0) and np.all(np.asarray(alpha)[:, 2] == 0)
    assert np.all(np.asarray(out)[2] == 0)
    # mean / sum aggregations over the active agents only
    out_mean, a_mean = gat_layer(w, x, mask, "mean")
    np.testing.assert_allclose(a_mean[:2, :2], np.full((2, 2), 0.5))
    out_sum, _ = gat_layer(w, x, mask, "sum")
    s = h[:2].sum(0)
    np.testing.assert_allclose(out_sum[0], np.where(s > 0, s, np.expm1(s)), rtol=1e-5)
    # the self term: x'_i = ELU(theta x_i + sum_j alpha_ij theta x_j), same weights alpha
    out_self, alpha_self = gat_layer(w, x, mask, "attention", self_term=True)
    expect_self = expect_alpha @ h[:2] + h[:2]
    np.testing.assert_allclose(alpha_self, alpha)
    np.testing.assert_allclose(
        out_self[:2], np.where(expect_self > 0, expect_self, np.expm1(expect_self)), rtol=1e-5
    )
    assert np.all(np.asarray(out_self)[2] == 0)


def test_gat_layer_masked_inputs_never_leak_even_nan():
    w = init_gat_weights(jax.random.PRNGKey(0), (3, 3))[0]
    x = jax.random.normal(jax.random.PRNGKey(1), (4, 3))
    mask = jnp.array([True, False, True, False])
    bad = x.at[1].set(jnp.nan).at[3].set(1e6)
    for agg, self_term in itertools.product(("attention", "mean", "sum"), (False, True)):
        out, alpha = gat_layer(w, x, mask, agg, self_term)
        out_bad, alpha_bad = gat_layer(w, bad, mask, agg, self_term)
        assert np.array_equal(out, out_bad) and np.array_equal(alpha, alpha_bad)
        layer = lambda x, agg=agg, st=self_term: gat_layer(w, x, mask, agg, st)[0].sum()
        grad = jax.grad(layer)(bad)
        assert np.all(np.isfinite(grad)) and np.all(np.asarray(grad)[[1, 3]] == 0)
    # all agents masked: zeros, no NaN
    out, alpha = gat_layer(w, x, jnp.zeros(4, bool), "attention")
    assert np.all(out == 0) and np.all(alpha == 0)


def test_flat_gat_weights_roundtrip():
    dims = (6, 4, 3)
    ws = init_gat_weights(jax.random.PRNGKey(0), dims)
    flat = flatten_gat_weights(ws)
    assert flat.shape == (gat_num_params(dims),) == (6 * 4 + 8 + 4 * 3 + 6,)
    back = unflatten_gat_weights(flat, dims)
    for a, b in zip(ws, back, strict=True):
        assert np.array_equal(a.theta, b.theta) and np.array_equal(a.attn, b.attn)
    with pytest.raises(ValueError, match="need"):
        unflatten_gat_weights(flat[:-1], dims)


# --- critic -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "cfg",
    ALL_CONFIGS,
    ids=lambda c: (
        f"{c.aggregation}-hyper{int(c.hypernet)}-asrl{int(c.asrl)}" + ("-self" * c.self_term)
    ),
)
def test_critic_permutation_and_masking_invariance(cfg, hvae_params, inputs):
    critic, params = make(cfg, hvae_params, inputs)
    obs, actions, dim_mask, c, _ = inputs
    mask = jnp.array([True, True, False, True])
    q = critic.apply({"params": params}, obs, actions, dim_mask, c, mask, hvae_params)
    assert q.shape == () and np.isfinite(q)
    perm = jnp.array([3, 0, 2, 1])
    q_perm = critic.apply(
        {"params": params}, obs, actions[perm], dim_mask[perm], c[perm], mask[perm], hvae_params
    )
    np.testing.assert_allclose(q_perm, q, rtol=1e-5, atol=1e-6)
    # Whatever a masked agent carries changes nothing (NaN included).
    q_bad = critic.apply(
        {"params": params},
        obs,
        actions.at[2].set(jnp.nan),
        dim_mask,
        c.at[2].set(37.0),
        mask,
        hvae_params,
    )
    assert np.array_equal(q_bad, q)
    # A padded agent (extra masked row) changes nothing either.
    pad = lambda x, v: jnp.concatenate([x, jnp.full((1, *x.shape[1:]), v, x.dtype)])
    q_pad = critic.apply(
        {"params": params},
        obs,
        pad(actions, 0.5),
        pad(dim_mask, True),
        pad(c, 1.0),
        pad(mask, False),
        hvae_params,
    )
    np.testing.assert_allclose(q_pad, q, rtol=1e-6, atol=1e-6)
    alpha = critic.apply(
        {"params": params},
        obs,
        actions,
        dim_mask,
        c,
        mask,
        hvae_params,
        method=GraphCritic.attention_weights,
    )
    assert alpha.shape == (cfg.gat_layers, N, N)
    alpha = np.asarray(alpha)
    assert np.all(alpha[:, 2, :] == 0) and np.all(alpha[:, :, 2] == 0)
    if cfg.aggregation != "sum":
        np.testing.assert_allclose(alpha[:, [0, 1, 3]].sum(-1), 1.0, rtol=1e-5)
    # Active agents do matter.
    q_moved = critic.apply(
        {"params": params}, obs, actions.at[0, 0].add(0.5), dim_mask, c, mask, hvae_params
    )
    assert q_moved != q


def test_aggregation_switch_changes_the_function(hvae_params, inputs):
    # Same params (the aggregation has none of its own), different function.
    critic, params = make(CCFG, hvae_params, inputs)
    qs = [
        GraphCritic(dataclasses.replace(CCFG, aggregation=a), HCFG, OBS, WIDTH).apply(
            {"params": params}, *inputs, hvae_params
        )
        for a in ("attention", "mean", "sum")
    ]
    assert len({float(q) for q in qs}) == 3


def test_hypernet_switch_uses_the_same_gat(hvae_params, inputs):
    hyper_critic, hp = make(CCFG, hvae_params, inputs)
    plain_cfg = dataclasses.replace(CCFG, hypernet=False)
    plain_critic, pp = make(plain_cfg, hvae_params, inputs)
    assert "hyper" in hp and "gat" not in hp and "gat" in pp and "hyper" not in pp
    # The plain critic with the hypernet's output as its weights is the hypernet critic.
    obs = inputs[0]
    dims = (CCFG.agent_dim,) * (CCFG.gat_layers + 1)
    # The per-layer weights it generates, flattened, are the plain critic's flat weight vector.
    flat = flatten_gat_weights(
        HyperNet(dims, CCFG.hyper_hidden).apply({"params": hp["hyper"]}, obs)
    )
    same = {"p_w": hp["p_w"], "f_xi": hp["f_xi"], "gat": {"weights": flat}}
    q_hyper = hyper_critic.apply({"params": hp}, *inputs, hvae_params)
    np.testing.assert_allclose(
        plain_critic.apply({"params": same}, *inputs, hvae_params), q_hyper, rtol=1e-5
    )
    # ... and the hypernet's weights depend on the state, so a fixed GAT is a different function.
    other_obs = -obs
    flat_other = flatten_gat_weights(
        HyperNet(dims, CCFG.hyper_hidden).apply({"params": hp["hyper"]}, other_obs)
    )
    assert not np.allclose(flat, flat_other)
    q_hyper_other = hyper_critic.apply({"params": hp}, other_obs, *inputs[1:], hvae_params)
    q_plain_other = plain_critic.apply({"params": same}, other_obs, *inputs[1:], hvae_params)
    assert abs(float(q_hyper_other - q_plain_other)) > 1e-6


def test_asrl_switch_freezes_the_hvae(hvae_params, inputs):
    critic, params = make(CCFG, hvae_params, inputs)
    hvae_names = {
        "obs_encoder",
        "action_encoder",
        "encoder",
        "decoder",
        "prior",
        "set_element",
        "space_head",
    }
    flat_names = {
        getattr(k, "key", None)
        for path, _ in jax.tree_util.tree_flatten_with_path(params)[0]
        for k in path
    }
    assert not flat_names & hvae_names and set(params) == {"p_w", "hyper", "f_xi"}
    g_hvae = jax.grad(lambda hp: critic.apply({"params": params}, *inputs, hp))(hvae_params)
    assert all(np.all(np.asarray(g) == 0) for g in jax.tree_util.tree_leaves(g_hvae))
    g_critic = jax.grad(lambda p: critic.apply({"params": p}, *inputs, hvae_params))(params)
    assert all(np.any(np.asarray(g) != 0) for g in jax.tree_util.tree_leaves(g_critic["p_w"]))
    # The HVAE does drive the critic: other HVAE params, other Q.
    other = jax.tree_util.tree_map(lambda x: x * 1.1, hvae_params)
    assert critic.apply({"params": params}, *inputs, other) != critic.apply(
        {"params": params}, *inputs, hvae_params
    )
    with pytest.raises(ValueError, match="hvae_params"):
        critic.apply({"params": params}, *inputs, None)

    # asrl=False: own encoder, trained with the critic; hvae_params ignored (None is fine).
    own_cfg = dataclasses.replace(CCFG, asrl=False)
    own, own_params = make(own_cfg, None, inputs)
    assert "encoder" in own_params
    q_none = own.apply({"params": own_params}, *inputs, None)
    assert q_none == own.apply({"params": own_params}, *inputs, hvae_params)
    g = jax.grad(lambda p: own.apply({"params": p}, *inputs, None))(own_params)
    assert any(np.any(np.asarray(x) != 0) for x in jax.tree_util.tree_leaves(g["encoder"]))
    mask = finetune_mask(own_params)
    assert not any(jax.tree_util.tree_leaves(mask["encoder"])) and all(
        jax.tree_util.tree_leaves(mask["p_w"])
    )


def test_twin_critic(hvae_params, inputs):
    twin = TwinCritic(CCFG, HCFG, OBS, WIDTH)
    params = jax.jit(twin.init)(jax.random.PRNGKey(5), *inputs, hvae_params)["params"]
    q = jax.jit(twin.apply)({"params": params}, *inputs, hvae_params)
    assert q.shape == (2,) and q[0] != q[1]
    leaf = jax.tree_util.tree_leaves(params["critics"]["p_w"])[0]
    assert leaf.shape[0] == 2
    # Each slice is a GraphCritic.
    one = jax.tree_util.tree_map(lambda x: x[1], params["critics"])
    np.testing.assert_allclose(
        GraphCritic(CCFG, HCFG, OBS, WIDTH).apply({"params": one}, *inputs, hvae_params),
        q[1],
        rtol=1e-5,
    )
    assert all(jax.tree_util.tree_leaves(finetune_mask(params)))
    # batched use, as the learner does it
    batch = jax.tree_util.tree_map(lambda x: jnp.stack([x, x, x]), inputs)
    qb = jax.jit(jax.vmap(lambda *a: twin.apply({"params": params}, *a, hvae_params)))(*batch)
    assert qb.shape == (3, 2)


def test_finetuned_asrl_encoders_start_as_the_hvae_and_train(hvae_params, inputs):
    """finetune_asrl: the twin critic owns encoders copied from the HVAE, so at the start it
    computes exactly the frozen critic's Q (same other params), and they get gradients while
    the HVAE itself is untouched; transfer keeps them frozen (finetune_mask)."""
    frozen_twin = TwinCritic(CCFG, HCFG, OBS, WIDTH)
    ft_cfg = dataclasses.replace(CCFG, finetune_asrl=True)
    ft_twin = TwinCritic(ft_cfg, HCFG, OBS, WIDTH)
    key = jax.random.PRNGKey(5)
    frozen_params = frozen_twin.init(key, *inputs, hvae_params)["params"]
    ft_params = with_asrl_encoders(ft_twin.init(key, *inputs, None)["params"], hvae_params)
    encoder = ft_params["critics"]["encoder"]
    assert set(encoder) == set(hvae_params)
    for twin in (0, 1):
        jax.tree.map(
            lambda e, h, t=twin: np.testing.assert_array_equal(e[t], h), encoder, hvae_params
        )
    # Same non-encoder params (same init key) + the HVAE's encoders = the frozen critic's Q.
    q_frozen = frozen_twin.apply({"params": frozen_params}, *inputs, hvae_params)
    q_ft = ft_twin.apply({"params": ft_params}, *inputs, None)
    np.testing.assert_allclose(q_ft, q_frozen, rtol=1e-5, atol=1e-6)
    g = jax.grad(lambda p: ft_twin.apply({"params": p}, *inputs, None).sum())(ft_params)
    leaves = jax.tree_util.tree_leaves(g["critics"]["encoder"])
    assert any(np.any(np.asarray(x) != 0) for x in leaves)
    assert not any(jax.tree_util.tree_leaves(finetune_mask(ft_params)["critics"]["encoder"]))


@pytest.mark.parametrize(
    "cfg", [CCFG, dataclasses.replace(CCFG, aggregation="mean", hypernet=False, asrl=False)]
)
def test_embeddings_read_the_same_params_and_pool_to_the_same_q(cfg, hvae_params, inputs):
    """Fig. 12's agent embeddings: asking for them changes neither the parameters nor Q, and
    f_xi of the GAT embeddings' mean over active agents is Q."""
    obs, actions, dim_mask, c, _ = inputs
    mask = jnp.array([True, False, True, True])
    critic, params = make(cfg, hvae_params, inputs)
    via_embeddings = critic.init(
        jax.random.PRNGKey(3), *inputs, hvae_params, method=GraphCritic.embeddings
    )["params"]
    assert jax.tree.structure(via_embeddings) == jax.tree.structure(params)
    jax.tree.map(np.testing.assert_array_equal, via_embeddings, params)
    args = (obs, actions, dim_mask, c, mask, hvae_params)
    q = critic.apply({"params": params}, *args)
    q_with, alpha, emb = critic.apply(
        {"params": params}, *args, return_attention=True, return_embeddings=True
    )
    assert q_with == q and alpha.shape == (cfg.gat_layers, N, N)
    emb_only = critic.apply({"params": params}, *args, method=GraphCritic.embeddings)
    jax.tree.map(np.testing.assert_array_equal, emb_only, emb)
    assert emb.p_w.shape == emb.gat.shape == (N, cfg.agent_dim)
    assert np.all(np.asarray(emb.gat)[1] == 0)  # the masked agent's row
    pooled = np.asarray(emb.gat)[[0, 2, 3]].mean(0)
    q_again = MLP((cfg.hidden,), 1).apply({"params": params["f_xi"]}, jnp.asarray(pooled))[0]
    np.testing.assert_allclose(q_again, q, rtol=1e-5, atol=1e-6)
    # the embeddings after p_w do not depend on the other agents: moving agent 0 moves only row 0
    moved = critic.apply(
        {"params": params},
        obs,
        actions.at[0, 0].add(0.5),
        dim_mask,
        c,
        mask,
        hvae_params,
        method=GraphCritic.embeddings,
    )
    changed = np.any(np.asarray(moved.p_w) != np.asarray(emb.p_w), axis=1)
    assert changed.tolist() == [True, False, False, False]


def test_mlp_on_parts_is_the_mlp_on_their_concatenation():
    # The critic and the action encoder feed [e_o, per-agent parts] as parts (ConcatDense):
    # same parameters and the same function as the broadcast concatenation, less work.
    from score_jax.networks.mlp import MLP

    mlp = MLP((8,), 4)
    e_o, actions, c = (
        jnp.arange(3.0),
        jax.random.normal(jax.random.PRNGKey(1), (5, 2)),
        jnp.full((5, 1), 0.5),
    )
    full = jnp.concatenate([jnp.broadcast_to(e_o, (5, 3)), actions, c], -1)
    params = mlp.init(jax.random.PRNGKey(0), full)
    same_init = mlp.init(jax.random.PRNGKey(0), (e_o, actions, c))
    jax.tree.map(np.testing.assert_array_equal, params, same_init)
    np.testing.assert_allclose(
        mlp.apply(params, (e_o, actions, c)), mlp.apply(params, full), rtol=1e-5, atol=1e-6
    )
