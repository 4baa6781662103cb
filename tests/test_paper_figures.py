"""The paper's multi-run figures (score_jax.evaluation.paper_figures): each renders a PNG from
small synthetic results, and the data functions return the right values."""

import dataclasses
import sys
import types

import jax
import jax.numpy as jnp
import matplotlib.image
import numpy as np
import pytest

from envs.greenhouse.env import make_greenhouse
from score_jax.core.failures import FailureMode
from score_jax.evaluation import paper_figures as pf
from score_jax.evaluation.robustness import MODES, settings_grid, tabulate
from score_jax.networks.mlp import MLP
from score_jax.run.build import build
from tests.tiny import TINY_SCORE, tiny_config


def assert_png(path):
    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(str(path))
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    assert np.ptp(image[..., :3]) > 0  # something was drawn


def sweep_json(returns: np.ndarray, n_agents: int, n_seeds: int) -> dict:
    """A robustness.json as ``run_sweep`` writes it, from ``returns [K, S, E]``."""
    settings = settings_grid(n_agents, n_seeds)
    table = tabulate(returns, settings, n_agents, n_seeds)
    per_seed = returns.reshape(-1, n_agents, len(MODES), n_seeds * returns.shape[-1]).mean(-1)
    return {
        **table.to_dict(),
        "n_seeds": n_seeds,
        "trained_seeds": list(range(returns.shape[0])),
        "per_trained_seed_mean": per_seed.tolist(),
    }


def synthetic_sweep(k: int, drop: float, seed: int, n_agents: int = 4, n_seeds: int = 5):
    """Returns that fall by ``drop`` per failed sub-space (less under ``default``)."""
    rng = np.random.default_rng(seed)
    f = np.asarray(settings_grid(n_agents, n_seeds).n_failed)
    m = np.asarray(settings_grid(n_agents, n_seeds).mode)
    base = 100.0 - drop * f * np.where(m == int(FailureMode.DEFAULT), 0.5, 1.0)
    returns = base[None, :, None] + rng.normal(0.0, 3.0, (k, len(f), 2))
    return sweep_json(returns, n_agents, n_seeds)


def test_robustness_band_is_over_trained_seeds_or_episodes_and_the_panels_render(tmp_path):
    three = synthetic_sweep(3, 10.0, 0)
    one = synthetic_sweep(1, 20.0, 1)
    b = pf.robustness_band(three, "random")
    per_seed = np.asarray(three["per_trained_seed_mean"])[:, :, 1]
    np.testing.assert_allclose(b["mean"], per_seed.mean(0))
    assert b["n"] == 3 and b["over"] == "trained seeds"
    assert np.all(b["lo"] < b["mean"]) and np.all(b["mean"] < b["hi"])
    np.testing.assert_array_equal(b["n_failed"], [0, 1, 2, 3])
    b1 = pf.robustness_band(one, "last")
    assert b1["over"] == "evaluation episodes" and b1["n"] == 5 * 2
    np.testing.assert_allclose(b1["mean"], np.asarray(one["mean"])[:, 2])
    with pytest.raises(ValueError, match="'zero' is not in this sweep"):
        pf.robustness_band(one, "zero")
    path = tmp_path / "fig7.png"
    pf.plot_robustness_panels({"SCORE": three, "ISAC": one}, str(path), "greenhouse")
    assert_png(path)


def test_ablation_shares_are_of_the_full_space_return_and_the_bars_render(tmp_path):
    result = {
        "n_failed": [0, 1, 2],
        "modes": ["default", "random", "last"],
        "mean": [[200.0, 200.0, 200.0], [150.0, 100.0, 210.0], [100.0, 50.0, 190.0]],
    }
    np.testing.assert_allclose(pf.robustness_shares(result, "random"), [1.0, 0.5, 0.25])
    np.testing.assert_allclose(pf.robustness_shares(result, "last"), [1.0, 1.05, 0.95])
    path = tmp_path / "fig11.png"
    ablations = {"SCORE": result, "AL+HN": synthetic_sweep(2, 15.0, 2, n_agents=3)}
    pf.plot_ablation_robustness(ablations, str(path), "ablations")
    assert_png(path)
    bad = {**result, "mean": [[-5.0] * 3, [-6.0] * 3, [-7.0] * 3]}
    with pytest.raises(ValueError, match="'MF\\+HN', mode 'default': the full-space mean return"):
        pf.plot_ablation_robustness({"MF+HN": bad}, str(tmp_path / "bad.png"))


def test_setpoints_per_decision_are_the_policies_setpoints(tmp_path):
    env = make_greenhouse(season_days=7)
    space, hours = env.space, np.arange(24)
    agent_index = np.arange(space.n)
    physical = np.zeros((space.n, space.max_dim), np.float32)
    physical[space.index("temperature"), :24] = 13.0 + 0.5 * hours
    physical[space.index("co2"), :24] = 400.0 + 10.0 * hours
    physical[space.index("lighting"), :2] = (6.0, 18.0)
    physical[space.index("irrigation"), :2] = (7.0, 17.0)
    constant = space.from_physical(jnp.asarray(physical))

    def by_day(state, key):  # 14 + the day's index °C every hour: shows which days decide
        x = jnp.asarray(physical).at[space.index("temperature"), :24].set(14.0 + state.t[0])
        return space.from_physical(x)[None]

    policies = {"yield": lambda _: lambda s, k: constant[None], "profit": lambda _: by_day}
    out = pf.season_setpoints(
        env, policies, {"yield": None, "profit": None}, agent_index, 3, jax.random.PRNGKey(0)
    )
    np.testing.assert_array_equal(out["yield"]["day"], [0, 3, 6])
    np.testing.assert_array_equal(out["yield"]["hours"], pf.SETPOINT_HOURS)
    want_t = 13.0 + 0.5 * np.asarray(pf.SETPOINT_HOURS)
    want_c = 400.0 + 10.0 * np.asarray(pf.SETPOINT_HOURS)
    np.testing.assert_allclose(out["yield"]["temperature"], np.tile(want_t, (3, 1)), atol=1e-4)
    np.testing.assert_allclose(out["yield"]["co2"], np.tile(want_c, (3, 1)), atol=1e-3)
    np.testing.assert_allclose(
        out["profit"]["temperature"], np.repeat([[14.0], [17.0], [20.0]], 4, axis=1), atol=1e-4
    )
    with pytest.raises(ValueError, match="hours must be"):
        pf.season_setpoints(env, policies, {}, agent_index, 3, jax.random.PRNGKey(0), (24,))
    path = tmp_path / "fig10.png"
    pf.plot_setpoints(out, str(path), "setpoints")
    assert_png(path)


@pytest.fixture(scope="module")
def score_variants(tmp_path_factory):
    """Tiny SCORE (ASRL with random frozen HVAE parameters instead of pretraining) and the
    AL+HN ablation (no ASRL) on the probe env, fresh agent states."""
    out = {}
    for label, asrl in (("SCORE", True), ("AL+HN", False)):
        critic = dataclasses.replace(TINY_SCORE.critic, asrl=asrl)
        cfg = tiny_config(
            tmp_path_factory.mktemp(label.replace("+", "_")),
            score=dataclasses.replace(TINY_SCORE, critic=critic),
        )
        run = build(cfg, restoring=True, log=lambda *a: None)
        frozen = None
        if asrl:
            template = run.algo.frozen_template()
            leaves, tree = jax.tree.flatten(template)
            keys = jax.random.split(jax.random.PRNGKey(1), len(leaves))
            frozen = jax.tree.unflatten(
                tree,
                [0.3 * jax.random.normal(k, x.shape) for k, x in zip(keys, leaves, strict=True)],
            )
        out[label] = (run, run.algo.off_policy.init(jax.random.PRNGKey(2), frozen))
    return out


def test_twin_embeddings_pool_to_each_twins_q(score_variants):
    run, agent = score_variants["SCORE"]
    nets = run.algo.networks
    b, n = 3, nets.n_agents
    obs = jax.random.normal(jax.random.PRNGKey(3), (b, nets.obs_size))
    action = jax.random.uniform(jax.random.PRNGKey(4), (b, n, nets.width), minval=-1, maxval=1)
    mask = jnp.asarray([[True] * n, [True, False] + [True] * (n - 2), [True] * n])
    q = nets.q_fn(agent.critic, agent.consts, obs, action, mask)
    emb = nets.agent_embeddings(agent.critic, agent.consts, obs, action, mask)
    d = nets.config.critic.agent_dim
    assert emb.p_w.shape == emb.gat.shape == (b, 2, n, d)
    assert np.all(np.asarray(emb.gat)[1, :, 1] == 0)  # the masked agent sends nothing
    w = np.asarray(mask & agent.consts.valid, np.float32)[:, None, :, None]
    pooled = (np.asarray(emb.gat) * w).sum(2) / w.sum(2)  # [B, 2, d]
    f_xi = MLP((nets.config.critic.hidden,), 1)
    for twin in range(2):
        params = jax.tree.map(lambda x, t=twin: x[t], agent.critic.net["critics"]["f_xi"])
        q_twin = f_xi.apply({"params": params}, jnp.asarray(pooled[:, twin]))[:, 0]
        np.testing.assert_allclose(q_twin, q[:, twin], rtol=1e-5, atol=1e-5)


def test_embeddings_over_episodes_and_their_tsne_render(score_variants, tmp_path):
    embeddings = {}
    for label, (run, agent) in score_variants.items():
        emb = pf.collect_agent_embeddings(
            run.env, run.algo, agent, run.agent_index, jax.random.PRNGKey(5), n_episodes=2
        )
        n, d = len(run.agent_index), run.algo.networks.config.critic.agent_dim
        assert emb["p_w"].shape == emb["gat"].shape == (2 * run.env.episode_length, n, d)
        assert np.all(np.isfinite(emb["gat"]))
        embeddings[label] = emb
    points = pf.tsne_2d(embeddings["SCORE"]["gat"].reshape(-1, d), perplexity=5.0)
    assert points.shape == (2 * run.env.episode_length * n, 2) and np.all(np.isfinite(points))
    path = tmp_path / "fig12.png"
    names = [run.env.space.names[i] for i in run.agent_index]
    pf.plot_agent_embeddings(embeddings, names, str(path), "agent embeddings", perplexity=5.0)
    assert_png(path)
    with pytest.raises(ValueError, match="expected \\[N, 2 agents"):
        pf.plot_agent_embeddings(embeddings, names[:2], str(tmp_path / "bad.png"))


def test_embeddings_refuse_an_algorithm_without_a_graph_critic_and_tsne_names_the_extra(
    monkeypatch,
):
    not_score = types.SimpleNamespace(name="isac", networks=object())
    with pytest.raises(ValueError, match="'isac' has no graph critic"):
        pf.collect_agent_embeddings(None, not_score, None, [0], jax.random.PRNGKey(0))
    monkeypatch.setitem(sys.modules, "sklearn.manifold", None)  # import fails as if missing
    with pytest.raises(ImportError, match="'paper' extra"):
        pf.tsne_2d(np.zeros((10, 3)))


def test_transfer_curves_from_a_comparison_render(tmp_path):
    rng = np.random.default_rng(0)
    curve = lambda s, top: {
        "seed": s,
        "steps": [100, 200, 300, 400],
        "returns": (np.linspace(0, top, 4) + rng.normal(0, 1, 4)).tolist(),
    }
    compare = {
        "rows": {
            "SCORE": {
                "full": {"per_seed": [1.0, 2.0]},
                "initial": {"per_seed": [3.0, 4.0, 5.0]},
                "converge": {"per_seed": [9.0], "curves": [curve(s, 10) for s in range(3)]},
            },
            "ISAC": {
                "initial": {"per_seed": [2.0]},
                "converge": {"per_seed": [5.0], "curves": [curve(0, 5)]},
            },
            "QMIX": {"full": {"per_seed": [1.0]}},  # no transfer row
        }
    }
    curves, initial = pf.transfer_curves_from_compare(compare)
    assert list(curves) == ["SCORE", "ISAC"] and initial["SCORE"] == [3.0, 4.0, 5.0]
    path = tmp_path / "fig6b.png"
    pf.plot_transfer_curves(curves, str(path), initial=initial)
    assert_png(path)


def test_transfer_panels_group_variants_with_score_as_the_reference():
    labels = ["SCORE", "PPO", "PPO-mask", "QMIX-penalty", "QMIX", "ASRL+AL"]
    assert pf.transfer_panels(labels) == [
        ("PPO", ["SCORE", "PPO", "PPO-mask"]),
        ("QMIX", ["SCORE", "QMIX-penalty", "QMIX"]),
        ("ASRL+AL", ["SCORE", "ASRL+AL"]),
    ]
    # SCORE keeps its own panel when it is the only row, or when its family has variants.
    assert pf.transfer_panels(["SCORE"]) == [("SCORE", ["SCORE"])]
    with_variant = pf.transfer_panels(["PPO", "SCORE-mask", "SCORE"])
    assert with_variant[0] == ("SCORE", ["SCORE-mask", "SCORE"])
    assert pf.transfer_panels(["PPO", "PPO-penalty"]) == [("PPO", ["PPO", "PPO-penalty"])]


def test_across_agents_share_separates_agent_from_state_spread():
    """Fig. 12's panel titles: 0 when the agents of a state coincide, 1 when only the agent
    matters; a GAT layer whose attention scores keep their sign gives every receiver the same
    weights (static attention on a complete graph), hence the same output."""
    from score_jax.networks.gat import GATWeights, gat_layer

    rng = np.random.default_rng(0)
    per_state = rng.normal(size=(50, 1, 8))
    per_agent = rng.normal(size=(1, 4, 8))
    assert pf.across_agents_share(np.repeat(per_state, 4, axis=1)) == 0.0
    assert pf.across_agents_share(np.repeat(per_agent, 50, axis=0)) == pytest.approx(1.0)
    assert 0.2 < pf.across_agents_share(per_state + per_agent) < 0.8
    x = jnp.asarray(np.abs(rng.normal(size=(4, 8))))  # positive features, weights, attention:
    w = GATWeights(jnp.eye(8), jnp.ones(16))  # every score a_i + a_j > 0, LeakyReLU linear
    out, alpha = gat_layer(w, x, jnp.ones(4, bool))
    np.testing.assert_allclose(alpha, np.repeat(alpha[:1], 4, axis=0), rtol=1e-6)
    np.testing.assert_allclose(out, np.repeat(out[:1], 4, axis=0), rtol=1e-6)  # one output
    # the self term keeps each agent's own features: the same weights, four outputs
    out_self, alpha_self = gat_layer(w, x, jnp.ones(4, bool), self_term=True)
    np.testing.assert_allclose(alpha_self, alpha)
    assert pf.across_agents_share(np.asarray(out_self)[None]) > 0.1
