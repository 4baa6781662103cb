"""Single-agent baselines trained by brax (SAC, PPO, H-PPO) on the probe env, the fixed-width
transfer variants (plain / mask / penalty, Table 3), transfer.py on them, and compare.py.

The probe's optimum is 1.0 per step (10 per 10-step episode). On the same evaluation seeds a
uniformly random policy scores about 0.42 per step and every sub-space at its default about
0.81, so a run passes at 0.9 per step (9.0 per episode). Measured with these tiny settings:
SAC ~0.99 (6k steps), PPO ~0.99 and H-PPO ~0.97 (20k steps).

The H-PPO runs share one program shape (steps, epochs, sizes), so the compilation cache makes
compare.py's full-space and transfer runs cheap after the first full-space run.
"""

import csv
import dataclasses
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.distribution import NormalTanhDistribution

from envs.probe import PROBE_SPACE, make_probe
from score_jax.agents.brax import agents as brax_agents
from score_jax.agents.brax.composite_dist import CompositeDistribution
from score_jax.agents.brax.config import BraxPPOConfig, BraxSACConfig, SingleAgentConfig
from score_jax.agents.brax.flat_env import BraxFlatEnv
from score_jax.agents.brax.hppo import hppo_head_mask, make_hppo_networks
from score_jax.evaluation.report import final_evaluation
from score_jax.evaluation.robustness import run_sweep
from score_jax.run.build import restore_run
from score_jax.run.config import TrainConfig
from score_jax.run.driver import train
from score_jax.run.validate import UsageError

THRESHOLD = 9.0  # return per 10-step episode: 0.9 per step
STEPS = 20_480  # 16 PPO iterations of 1280 env steps
TINY_SINGLE = SingleAgentConfig(
    hidden=(32, 32),
    head_hidden=16,
    num_envs=16,
    learning_rate=3e-3,
    discounting=0.9,
    epochs=2,
    ppo=BraxPPOConfig(unroll_length=10, batch_size=32, num_minibatches=4, updates_per_batch=4),
    sac=BraxSACConfig(batch_size=64, min_replay_size=320, grad_updates_per_step=4),
)
silent = lambda *a, **k: None


def tiny(run_dir, algo: str, **overrides) -> TrainConfig:
    # SAC: brax's temperature starts at 1, so scale the probe's ~1 per-step reward up to learn in
    # 6k steps.
    single = dataclasses.replace(TINY_SINGLE, reward_scaling=10.0) if algo == "sac" else TINY_SINGLE
    base = TrainConfig(
        env="probe",
        algo=algo,
        total_steps=6000 if algo == "sac" else STEPS,
        run_dir=str(run_dir),
        quiet=True,
        eval_episodes=16,
        robustness_seeds=0,
        single=single,
    )
    return dataclasses.replace(base, **overrides)


@pytest.fixture(scope="module")
def full_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("single")
    return {algo: train(tiny(base / algo, algo), log=silent) for algo in ("sac", "ppo", "hppo")}


@pytest.mark.parametrize("algo", ["sac", "ppo", "hppo"])
def test_baseline_learns_the_probe_and_its_checkpoint_is_evaluated_and_swept(full_runs, algo):
    run = full_runs[algo]
    rows = list(csv.DictReader(open(os.path.join(run.run_dir, "metrics.csv"))))
    assert len(rows) >= 2 and int(rows[-1]["env_steps"]) >= run.config.total_steps
    assert all(np.isfinite(float(r["actor_loss"])) for r in rows if r["actor_loss"] != "nan")
    restored = restore_run(run.run_dir, log=silent)
    jax.tree.map(np.testing.assert_array_equal, restored.state.agent, run.state.agent)
    ev = final_evaluation(restored, 16, log=silent)
    assert ev[algo]["mean"] >= THRESHOLD > max(ev["default"]["mean"], ev["random"]["mean"])
    table = run_sweep(restored, n_seeds=2, log=silent)
    assert table.mean.shape == (3, 3) and np.isfinite(table.mean).all()
    assert table.mean[2, 1] < table.mean[0, 0] - 0.5  # two sub-spaces failing at random hurt
    assert os.path.exists(os.path.join(run.run_dir, "robustness.json")) and os.path.exists(
        os.path.join(run.run_dir, "evaluation.json")
    )


def test_resume_of_a_brax_run_is_refused_with_a_reason(full_runs):
    with pytest.raises(UsageError, match="cannot be continued exactly"):
        train(TrainConfig(resume=full_runs["ppo"].run_dir, quiet=True), log=silent)


def test_hppo_log_prob_counts_real_dims_only_and_discrete_heads_are_categorical():
    dist = CompositeDistribution(
        PROBE_SPACE
    )  # a: 2 continuous, b: 3 continuous, c: 1 discrete (5 choices)
    assert dist.head_sizes == (4, 6, 5) and dist.param_size == 15
    params = jax.random.normal(jax.random.PRNGKey(0), (7, 15))

    @jax.jit
    def compute(params):
        raw = dist.sample_no_postprocessing(params, jax.random.PRNGKey(1))
        k = jnp.round(raw[:, 5]).astype(jnp.int32)
        # reference: brax's tanh-normal on exactly the 5 continuous dims + the categorical's
        # log-softmax
        gauss = jnp.concatenate(
            [params[:, jnp.array([0, 1, 4, 5, 6])], params[:, jnp.array([2, 3, 7, 8, 9])]], axis=-1
        )
        ref = (
            NormalTanhDistribution(5).log_prob(gauss, raw[:, :5])
            + jax.nn.log_softmax(params[:, 10:])[jnp.arange(7), k]
        )
        draws = jax.vmap(lambda key: dist.sample_no_postprocessing(params[0], key)[5])(
            jax.random.split(jax.random.PRNGKey(2), 4000)
        )
        return raw, dist.log_prob(params, raw), ref, dist.postprocess(raw), dist.mode(params), draws

    raw, log_prob, ref, action, mode, draws = compute(params)
    k = np.asarray(raw[:, 5])
    assert raw.shape == (7, 6) and np.array_equal(k, np.round(k)) and k.min() >= 0 and k.max() <= 4
    np.testing.assert_allclose(log_prob, ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(action[:, :5], np.tanh(raw[:, :5]), rtol=1e-5)
    np.testing.assert_allclose(action[:, 5], -1.0 + 2.0 * k / 4)
    np.testing.assert_allclose(mode[:, 5], -1.0 + 2.0 * np.argmax(params[:, 10:], -1) / 4)
    freq = (
        np.bincount(np.asarray(draws, int), minlength=5) / 4000
    )  # the discrete head samples its softmax
    np.testing.assert_allclose(freq, jax.nn.softmax(params[0, 10:]), atol=0.03)
    # one sub-actor head per sub-space over a shared trunk
    nets = make_hppo_networks(PROBE_SPACE, (32,), 16)(4, 6)
    names = set(jax.eval_shape(nets.policy_network.init, jax.random.PRNGKey(0))["params"])
    assert names == {"trunk_0", "head_0", "head_1", "head_2"}


def test_unseen_heads_of_the_flat_mlp_are_their_output_columns():
    nets = ppo_networks.make_ppo_networks(4, 6, policy_hidden_layer_sizes=(8,))
    params = nets.policy_network.init(jax.random.PRNGKey(0))
    mask = brax_agents.mlp_head_mask(PROBE_SPACE, np.array([False, True, False]), params)
    expected = np.zeros(12, bool)
    expected[[2, 3, 4, 8, 9, 10]] = True  # b's 3 means and 3 scales
    np.testing.assert_array_equal(
        np.broadcast_to(mask["params"]["hidden_1"]["kernel"], (8, 12))[0], expected
    )
    np.testing.assert_array_equal(mask["params"]["hidden_1"]["bias"], expected)
    assert not np.any(mask["params"]["hidden_0"]["kernel"])


def test_flat_env_gives_uncontrolled_subspaces_their_defaults():
    env = make_probe()
    flat = BraxFlatEnv(env, controlled=np.array([True, True, False]))
    action = jnp.array([0.1, -0.2, 0.3, 0.4, 0.5, 1.0])  # c asks for its last choice

    @jax.jit
    def errors(key):
        state = flat.reset(key)
        got = flat.step(state, action).pipeline_state.metrics.squared_error
        return got, env.step(
            state.pipeline_state, PROBE_SPACE.unflatten(action.at[5].set(0.0))
        ).metrics.squared_error  # c at its default

    got, expected = errors(jax.random.PRNGKey(0))
    np.testing.assert_allclose(got, expected)


def _head(agent, i):
    return agent[1]["params"][f"head_{i}"]


def _changed(a, b) -> bool:
    return any(
        not np.array_equal(x, y)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


def test_variants_mask_trains_unseen_heads_and_penalty_pulls_them_to_the_default():
    """100 Adam steps of an on-policy policy gradient (log-prob of freshly sampled composite
    actions times advantages that ignore c: the gradient c's head gets in a run on {a, b})
    through each variant's policy forward pass: c's head (head_2) is moved by ``mask`` and
    pulled towards c's default by ``penalty`` (``plain`` is checked bitwise in a brax run in
    the compare test). The sampling noise is drawn outside the compiled step: PRNG code is slow
    to compile on CPU."""
    import optax

    factory = make_hppo_networks(PROBE_SPACE, (32,), 16)
    fresh = factory(4, 6)
    dist = fresh.parametric_action_distribution
    params0 = fresh.policy_network.init(jax.random.PRNGKey(0))
    obs = jax.random.uniform(jax.random.PRNGKey(1), (256, 4), minval=-1, maxval=1)
    keys = jax.random.split(jax.random.PRNGKey(2), 3)
    noise = (
        jax.random.normal(keys[0], (100, 256, 5)),
        jax.random.gumbel(keys[1], (100, 256, 1, 5)),
        jax.random.normal(keys[2], (100, 256)),
    )
    target = PROBE_SPACE.flatten(PROBE_SPACE.default_action())
    deviation = lambda p: float(
        jnp.mean(dist.deviation(fresh.policy_network.apply(None, p, obs), target)[:, 5])
    )
    opt = optax.adam(3e-3)
    out = {}
    for variant in ("mask", "penalty"):
        apply = brax_agents.variant_factory(
            factory, PROBE_SPACE, np.array([True, True, False]), variant, 1.0, hppo_head_mask
        )(4, 6).policy_network.apply

        def loss(p, eps, gumbel, advantage, apply=apply):
            logits = apply(None, p, obs)
            d = dist.create_dist(
                jax.lax.stop_gradient(logits)
            )  # raw sample: a, b (5 pre-tanh values), c (choice index)
            raw = jnp.concatenate(
                [
                    d.gauss_loc + d.gauss_scale * eps,
                    jnp.argmax(d.logits + gumbel, -1).astype(jnp.float32),
                ],
                -1,
            )
            return -jnp.mean(dist.log_prob(logits, raw) * advantage)

        def step(carry, noise, loss=loss):
            params, opt_state = carry
            updates, opt_state = opt.update(jax.grad(loss)(params, *noise), opt_state)
            return (optax.apply_updates(params, updates), opt_state), None

        out[variant] = jax.jit(
            lambda p, noise, step=step: jax.lax.scan(step, (p, opt.init(p)), noise)[0][0]
        )(params0, noise)
    head = lambda p, i: p["params"][f"head_{i}"]
    assert _changed(head(out["mask"], 2), head(params0, 2)) and _changed(
        head(out["penalty"], 0), head(params0, 0)
    )
    assert deviation(out["penalty"]) < 0.5 * min(deviation(out["mask"]), deviation(params0))


def test_compare_runs_plain_subset_and_transfer_and_writes_tables_and_curves(tmp_path):
    """compare.py on the probe with H-PPO: the full-space run, the plain subset run on {a, b}
    (c's head stays bitwise at the parameters brax started from) and transfer.py's fine-tuning
    on the full space (every head moves, the return reaches the threshold)."""
    from benchmarks.compare import CompareArgs, main

    args = CompareArgs(
        envs=("probe",),
        algos=("hppo",),
        ablations="none",
        seeds=1,
        total_steps=STEPS,
        transfer=True,
        variants=("plain",),
        eval_points=2,
        eval_episodes=16,
        out=str(tmp_path / "out"),
        work_dir=str(tmp_path / "work"),
        base=TrainConfig(quiet=True, robustness_seeds=0, single=TINY_SINGLE),
    )
    assert main(args) == 0
    out = json.load(open(tmp_path / "out" / "compare_probe.json"))
    row = out["rows"]["H-PPO"]
    assert len(row["full"]["per_seed"]) == 1 and row["full"]["mean"] >= THRESHOLD
    assert row["full"]["curves"][0]["steps"] == [
        0,
        STEPS // 2,
        STEPS,
    ]  # the starting policy, then every --eval-every steps
    assert np.isfinite(row["initial"]["mean"]) and row["converge"]["mean"] >= THRESHOLD
    assert "| H-PPO |" in open(tmp_path / "out" / "compare_probe.md").read()
    for png in ("compare_probe.png", "compare_probe_transfer.png"):
        assert (tmp_path / "out" / png).stat().st_size > 10_000

    subset = restore_run(
        str(tmp_path / "work" / "probe" / "h-ppo-plain-subset" / "s0"), log=silent
    ).for_seed(0)
    initial = subset.trainer.init(
        jax.random.split(jax.random.PRNGKey(0))[1]
    ).agent  # what brax started from (seed 0)
    jax.tree.map(
        np.testing.assert_array_equal, _head(subset.state.agent, 2), _head(initial, 2)
    )  # plain: frozen, bitwise
    assert _changed(_head(subset.state.agent, 0), _head(initial, 0)) and _changed(
        _head(subset.state.agent, 1), _head(initial, 1)
    )
    grown = restore_run(
        str(tmp_path / "work" / "probe" / "h-ppo-plain-transfer" / "s0"), log=silent
    ).for_seed(0)
    assert list(grown.agent_index) == [0, 1, 2] and grown.transfer.new == ("c",)
    assert all(
        _changed(_head(grown.state.agent, i), _head(subset.state.agent, i)) for i in range(3)
    )  # transfer fine-tunes every head
    assert main(args) == 0  # a second call reuses every run's result.json
