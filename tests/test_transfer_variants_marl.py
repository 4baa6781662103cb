"""Transfer variants of the multi-agent baselines (Table 3: MADDPG, QMIX, MAAC -plain/-mask/
-penalty): a subset run on the probe's {b, c} builds every sub-space's agent, a (two continuous
dims) reaches the environment and the critic at its default, ``plain`` keeps a's policy
bitwise, ``mask`` moves it, ``penalty`` adds a positive term that pulls a's deterministic
sub-action to its default, and score-transfer fine-tunes the same networks on the full space."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.agents import variants
from score_jax.agents.marl.config import MarlConfig
from score_jax.agents.replay import replay_sample
from score_jax.evaluation.transfer import TransferArgs, run_transfer
from score_jax.networks.actor import ActorConfig
from score_jax.run.build import build, seed_keys
from score_jax.run.config import SingleAgentConfig
from score_jax.run.driver import train
from score_jax.run.validate import validate_train_config
from tests.tiny import TINY_OFF_POLICY, tiny_config

ALGOS = ("maddpg", "qmix", "maac")
SMALL = MarlConfig(
    actor=ActorConfig(hidden=(16,)),
    critic_hidden=(16,),
    maac_embed_dim=8,
    maac_heads=2,
    qmix_candidates=8,
    qmix_mixer_dim=8,
)
SEEN = np.array([False, True, True])  # the probe's b, c seen; a unseen
silent = lambda *a: None


def variant_config(run_dir, algo, variant, **overrides):
    """Two epochs of 200 decisions (updates in the second) on {b, c}."""
    return tiny_config(
        run_dir,
        algo=algo,
        subspaces="b,c",
        total_steps=400,
        checkpoint_every=400,
        eval_every=0,
        robustness_seeds=0,
        marl=SMALL,
        off_policy=dataclasses.replace(TINY_OFF_POLICY, learning_starts=200, batch_size=32),
        single=SingleAgentConfig(transfer_variant=variant, penalty_coef=10.0),
        **overrides,
    )


@pytest.fixture(scope="module")
def subset_run(tmp_path_factory):
    """``subset_run(algo)``: a ``mask`` run on {b, c}, trained on first use."""
    runs = {}

    def get(algo):
        if algo not in runs:
            run_dir = tmp_path_factory.mktemp("variants") / algo
            runs[algo] = train(variant_config(run_dir, algo, "mask"), log=silent)
        return runs[algo]

    return get


def _policy(algo, agent):
    """The per-agent policy parameters (QMIX: its agent Q networks)."""
    return agent.params["agent_q"] if algo == "qmix" else agent.actor


def _row(tree, i):
    return [np.asarray(x)[i] for x in jax.tree.leaves(tree)]


def _changed(tree, other, i) -> bool:
    """Whether agent ``i``'s rows differ anywhere between the two per-agent trees."""
    return any(not np.array_equal(x, y) for x, y in zip(_row(tree, i), _row(other, i), strict=True))


def _det(run, agent, obs, algo):
    """Every sub-space's deterministic sub-action ``[B, n, w]`` (MADDPG, MAAC: the networks'
    full agent set)."""
    nets = run.algo.networks
    if algo == "maddpg":
        return nets.policy_fn(agent.actor, agent.consts, obs)
    return nets.policy_fn(agent.actor, agent.consts, obs, jax.random.PRNGKey(0), True)[0]


@pytest.mark.parametrize("algo", ALGOS)
def test_subset_run_builds_every_agent_and_a_gets_its_default(subset_run, algo):
    run = subset_run(algo).for_seed(0)
    space, agent = run.env.space, run.state.agent
    assert len(run.agent_index) == 2 and int(run.state.updates) > 0
    assert all(x.shape[0] == 3 for x in jax.tree.leaves(_policy(algo, agent)))  # a, b and c
    default = np.asarray(space.default_action())
    # what the environments received at the last step: a at its default
    np.testing.assert_array_equal(
        np.asarray(run.state.last_action)[:, 0], default[None, 0].repeat(8, 0)
    )
    # the batch the update sees: a at the default the environment received, always active
    batch = replay_sample(run.state.buffer, jax.random.PRNGKey(0), 16)
    lifted = variants.lift_batch(space, batch, run.agent_index, SEEN)
    np.testing.assert_array_equal(
        np.asarray(lifted.action)[:, 0, : space.max_dim], default[None, 0].repeat(16, 0)
    )
    assert np.asarray(lifted.active)[:, 0].all()
    # a critic is evaluated on what the environment receives: a's action does not change it,
    # yet a's actor gets its gradient (straight through the replacement)
    moved = batch.action.at[:, :, 0].set(0.5)
    full = jnp.concatenate([jnp.full((16, 1, moved.shape[-1]), 0.7), moved], 1)
    passed = variants.pass_unseen(space, full, SEEN)
    np.testing.assert_array_equal(
        np.asarray(passed)[:, 0, : space.max_dim], default[None, 0].repeat(16, 0)
    )
    grad = jax.grad(lambda a: jnp.sum(variants.pass_unseen(space, a, SEEN)))(full)
    np.testing.assert_array_equal(np.asarray(grad)[:, 0, : space.max_dim], 1.0)


@pytest.mark.parametrize("algo", ALGOS)
def test_plain_freezes_a_mask_moves_it_penalty_pulls_it_to_the_default(subset_run, algo, tmp_path):
    """``mask``: the subset run itself moved a's policy from where it started. ``plain`` and
    ``penalty``: from the trained networks (fresh optimiser states), 20 updates on the same
    batches; plain keeps a's rows bitwise, penalty pulls its deterministic sub-action nearer its
    default (b's rows move under both)."""
    run = subset_run(algo).for_seed(0)
    state, space = run.state, run.env.space
    start = run.trainer.init(seed_keys(run.seeds)[1][0]).agent
    assert _changed(_policy(algo, state.agent), _policy(algo, start), 0)  # mask
    batches = [replay_sample(state.buffer, jax.random.PRNGKey(k), 32) for k in range(20)]
    obs = batches[0].obs
    default = jnp.asarray(space.default_action())

    def deviation(agent):
        """The penalty's deviation (QMIX: the Boltzmann expectation over its candidates)."""
        if algo == "qmix":
            nets = run.algo.networks
            return float(
                jnp.mean(nets.expected_deviation(nets.q_values(agent.params, agent.consts, obs)))
            )
        det = _det(run, agent, obs, algo)[..., : space.max_dim]
        return float(jnp.mean(variants.agent_deviation(det, default, space.dim_mask, ~SEEN)))

    out = {}
    for variant in ("plain", "penalty"):
        cfg = dataclasses.replace(
            run.config, single=SingleAgentConfig(transfer_variant=variant, penalty_coef=10.0)
        )
        algo_v = build(cfg, run_dir=str(tmp_path / variant), restoring=True, log=silent).algo
        update = jax.jit(algo_v.off_policy.update)
        # the trained networks with fresh optimiser states (as a run of this variant has them)
        fresh = algo_v.off_policy.init(jax.random.PRNGKey(1))
        agent = algo_v.grow(state.agent, fresh, None, jax.random.PRNGKey(2))
        for k, batch in enumerate(batches):
            agent, _ = update(agent, batch, jax.random.PRNGKey(100 + k), algo_v.off_policy.hyper)
        out[variant] = agent
    before = _policy(algo, state.agent)
    jax.tree.map(
        np.testing.assert_array_equal, _row(_policy(algo, out["plain"]), 0), _row(before, 0)
    )
    assert _changed(_policy(algo, out["penalty"]), before, 0)
    assert all(_changed(_policy(algo, agent), before, 1) for agent in out.values())
    # the penalty term is positive, and its pull brings a's deterministic sub-action nearer
    assert deviation(state.agent) > 0.0
    # (QMIX's Q values start near 0, so its Boltzmann choice moves slowly at this learning rate)
    factor = 1.0 if algo == "qmix" else 0.9
    assert deviation(out["penalty"]) < factor * deviation(state.agent)


@pytest.mark.parametrize("algo", ALGOS)
def test_transfer_fine_tunes_the_same_networks(subset_run, algo, tmp_path):
    """Transfer starts from the trained networks (every agent where it was; fresh optimiser
    states) and fine-tunes them for one epoch of updates on the full space."""
    run = subset_run(algo)
    one = run.for_seed(0)
    template = one.algo.off_policy.init(jax.random.PRNGKey(5))
    kept = one.algo.grow(one.state.agent, template, None, jax.random.PRNGKey(6))
    jax.tree.map(np.testing.assert_array_equal, _policy(algo, kept), _policy(algo, one.state.agent))
    result = run_transfer(
        TransferArgs(
            checkpoint=run.run_dir,
            total_steps=400,
            run_dir=str(tmp_path / "t"),
            eval_episodes=2,
            quiet=True,
        ),
        log=silent,
    )
    assert result["new_subspaces"] == ["a"]
    assert np.isfinite(result["initial"]["mean"]) and np.isfinite(result["converge"]["mean"])


def test_variant_for_an_algorithm_without_variants_is_one_clear_error(tmp_path):
    for algo in ("isac", "score"):
        problems = validate_train_config(variant_config(tmp_path / algo, algo, "mask"))
        assert [p for p in problems if "transfer-variant" in p] == [
            f"--single.transfer-variant mask: {algo} has no transfer variants (they are for the "
            "baselines built for the full space: hppo, maac, maddpg, ppo, qmix, sac)"
        ]
