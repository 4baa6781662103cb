"""Transfer to unseen sub-spaces (§4.3) on the probe: train on {a, b}, grow by c."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.agents import growth as tr
from score_jax.agents.replay import replay_sample
from score_jax.agents.score.transfer import embed_new, grow_agent, transfer_optimizers
from score_jax.evaluation.transfer import TransferArgs, run_transfer
from score_jax.run.build import build, restore_run
from score_jax.run.config import TransferSpec
from score_jax.run.driver import train
from score_jax.run.validate import UsageError
from tests.tiny import tiny_config

pytestmark = pytest.mark.slow  # scheduled first (conftest)


@pytest.fixture(scope="module")
def subset_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("transfer") / "subset"
    train(tiny_config(run_dir, subspaces="a,b", total_steps=600), log=lambda *a: None)
    return restore_run(str(run_dir), log=lambda *a: None).for_seed(0)


@pytest.fixture(scope="module")
def grown(subset_run):
    """The grown run's structure and the grown algorithm state (before any fine-tuning)."""
    p = tr.plan(subset_run.agent_index, np.arange(3))
    cfg = dataclasses.replace(subset_run.config, subspaces="a,b,c")
    spec = TransferSpec(subset_run.run_dir, ("c",))
    run = build(
        cfg,
        jax.random.PRNGKey(0),
        "/tmp/unused",
        restoring=True,
        log=lambda *a: None,
        transfer=spec,
    ).for_seed(0)
    new_c = embed_new(subset_run.state.agent, run.algo.networks, run.env, p, jax.random.PRNGKey(3))
    template = run.trainer.init(jax.random.PRNGKey(1)).agent
    return run, p, grow_agent(subset_run.state.agent, template, p, new_c, jax.random.PRNGKey(2))


def test_plan_orders_agents_like_the_space(subset_run):
    p = tr.plan(subset_run.agent_index, [2, 0, 1])
    np.testing.assert_array_equal(p.agent_index, [0, 1, 2])
    np.testing.assert_array_equal(p.is_new, [False, False, True])
    with pytest.raises(ValueError, match="must include"):
        tr.plan([0, 1], [0, 2])
    with pytest.raises(ValueError, match="no new sub-space"):
        tr.plan([0, 1], [0, 1])


def test_grown_critic_with_new_agent_masked_equals_restored(subset_run, grown):
    run, p, agent = grown
    src_nets, src_agent = subset_run.algo.networks, subset_run.state.agent
    batch = replay_sample(subset_run.state.buffer, jax.random.PRNGKey(0), 32)
    q_src = src_nets.q_fn(
        src_agent.critic, src_agent.consts, batch.obs, batch.action, jnp.ones((32, 2), bool)
    )
    junk = jax.random.uniform(
        jax.random.PRNGKey(5), (32, 1, batch.action.shape[-1]), minval=-1, maxval=1
    )
    actions = jnp.concatenate([batch.action, junk], axis=1)  # agents a, b, c in the space's order
    mask = jnp.broadcast_to(jnp.array([True, True, False]), (32, 3))
    q_grown = run.algo.networks.q_fn(agent.critic, agent.consts, batch.obs, actions, mask)
    np.testing.assert_allclose(q_grown, q_src, rtol=1e-6, atol=1e-6)
    # the old agents keep their actors: same deterministic sub-actions as before
    a_src = src_nets.policy_fn(
        src_agent.actor, src_agent.consts, batch.obs, jax.random.PRNGKey(0), True
    )[0]
    a_new = run.algo.networks.policy_fn(
        agent.actor, agent.consts, batch.obs, jax.random.PRNGKey(0), True
    )[0]
    np.testing.assert_array_equal(a_new[:, :2], a_src)
    # the new sub-space's code comes from the frozen HVAE and differs from the old ones
    c = agent.consts.critic_inputs.c
    np.testing.assert_array_equal(c[:2], src_agent.consts.critic_inputs.c)
    assert float(jnp.min(jnp.linalg.norm(c[:2] - c[2], axis=-1))) > 1e-3


def test_new_actors_start_untrained_unless_asked(subset_run, grown):
    """§4.3: the new actor of c starts untrained (~uniform choices); --new-actor-prior starts it
    at c's default choice (index 2, normalised 0) like the old actors' prior."""
    run, p, agent = grown
    obs = jax.random.uniform(jax.random.PRNGKey(4), (512, 4), minval=-1, maxval=1)
    share = lambda a: float(jnp.mean(jnp.abs(a[:, 2, 0]) < 1e-3))  # c played at its default
    policy = run.algo.networks.policy_fn
    assert agent.consts.prior_agents.tolist() == [True, True, False]
    assert share(policy(agent.actor, agent.consts, obs, jax.random.PRNGKey(5))[0]) < 0.4
    spec = TransferSpec(subset_run.run_dir, ("c",), new_actor_prior=True)
    cfg = dataclasses.replace(subset_run.config, subspaces="a,b,c")
    primed = build(cfg, None, "/tmp/unused", restoring=True, log=lambda *a: None, transfer=spec)
    template = primed.for_seed(0).trainer.init(jax.random.PRNGKey(1)).agent
    new_c = agent.consts.critic_inputs.c[2:]
    agent = grow_agent(subset_run.state.agent, template, p, new_c, jax.random.PRNGKey(2))
    assert agent.consts.prior_agents is None  # every actor acts around its default
    assert share(policy(agent.actor, agent.consts, obs, jax.random.PRNGKey(5))[0]) > 0.65
    assert share(policy(agent.actor, agent.consts, obs, jax.random.PRNGKey(5), True)[0]) == 1.0


def test_frozen_parts_are_bitwise_unchanged_after_a_finetuning_step(subset_run, grown):
    run, p, agent = grown
    batch = replay_sample(subset_run.state.buffer, jax.random.PRNGKey(1), 64)
    junk = jnp.zeros((64, 1, batch.action.shape[-1]))
    batch = batch.replace(
        action=jnp.concatenate([batch.action, junk], 1), active=jnp.ones((64, 3), bool)
    )
    new, _ = jax.jit(run.algo.off_policy.update)(
        agent, batch, jax.random.PRNGKey(0), run.algo.off_policy.hyper
    )
    for old, upd in zip(jax.tree.leaves(agent.actor), jax.tree.leaves(new.actor), strict=True):
        np.testing.assert_array_equal(np.asarray(upd)[:2], np.asarray(old)[:2])  # old actors frozen
    assert any(
        not np.array_equal(np.asarray(u)[2], np.asarray(o)[2])
        for o, u in zip(jax.tree.leaves(agent.actor), jax.tree.leaves(new.actor), strict=True)
    )
    jax.tree.map(
        np.testing.assert_array_equal, new.consts.critic_inputs, agent.consts.critic_inputs
    )  # HVAE and c_i frozen
    jax.tree.map(
        np.testing.assert_array_equal,
        new.critic.net["critics"]["encoder"],
        agent.critic.net["critics"]["encoder"],
    )  # the critic's own encoders frozen (this spec's finetune_critic_encoder is False)
    assert any(
        not np.array_equal(a, b)
        for a, b in zip(jax.tree.leaves(agent.critic), jax.tree.leaves(new.critic), strict=True)
    )  # p_w, GAT, f_xi train


def test_finetune_critic_encoder_opens_only_the_critics_encoders(grown):
    """With ``finetune_critic_encoder`` (score-transfer's default) the critic optimiser of a
    transfer run updates the critic's own encoders too; without it (--freeze-critic-encoder)
    they get exactly zero updates; every other critic subtree trains either way."""
    run, _, agent = grown
    sc = run.algo.networks.config
    trainable = np.array([False, False, True])
    grads = jax.tree.map(jnp.ones_like, agent.critic)
    steps = {}
    for flag in (False, True):
        _, critic_opt, _ = transfer_optimizers(sc, trainable, flag)
        updates, _ = critic_opt.update(grads, critic_opt.init(agent.critic), agent.critic)
        steps[flag] = updates.net["critics"]
    moved = lambda tree: [bool(np.any(np.asarray(x) != 0)) for x in jax.tree.leaves(tree)]
    assert not any(moved(steps[False]["encoder"])) and all(moved(steps[True]["encoder"]))
    for name in set(steps[True]) - {"encoder"}:
        assert all(moved(steps[True][name])) and all(moved(steps[False][name])), name


def test_transfer_cli_reports_initial_and_converge(subset_run, tmp_path, caplog):
    out = tmp_path / "grown"
    with jax.log_compiles(True), caplog.at_level("WARNING"):
        result = run_transfer(
            TransferArgs(
                checkpoint=subset_run.run_dir,
                total_steps=400,
                run_dir=str(out),
                quiet=True,
                eval_episodes=4,
            ),
            log=lambda *a: None,
        )
    # the grown state is placed like a fresh one: the training epoch compiles once, not again
    # after its first call (which it did while the grown agent was not committed to a device)
    assert sum("Compiling jit(_epoch)" in r.getMessage() for r in caplog.records) == 1
    assert result["new_subspaces"] == ["c"]
    assert np.isfinite(result["initial"]["mean"]) and np.isfinite(result["converge"]["mean"])
    saved = json.load(open(out / "transfer.json"))
    assert saved["initial"] == result["initial"]
    # the new actor of c started untrained: only a and b act around their defaults
    config = json.load(open(out / "config.json"))
    assert config["resolved"]["default_prior"] == ["a", "b"] and config["default_prior"]
    assert config["transfer"]["new_actor_prior"] is False
    assert (out / "transfer.png").stat().st_size > 10_000
    # the fine-tuned run is an ordinary run over all sub-spaces: it restores and evaluates
    restored = restore_run(str(out), log=lambda *a: None).for_seed(0)
    assert list(restored.agent_index) == [0, 1, 2] and int(restored.state.env_steps) == 400
    # by default the critic's own encoders fine-tuned (--freeze-critic-encoder keeps them)
    assert config["transfer"]["finetune_critic_encoder"] is True
    encoders = [s.state.agent.critic.net["critics"]["encoder"] for s in (subset_run, restored)]
    assert any(
        not np.array_equal(a, b) for a, b in zip(*map(jax.tree.leaves, encoders), strict=True)
    )


def test_checkpoint_from_another_env_is_refused(subset_run, tmp_path):
    with pytest.raises(UsageError, match="--env greenhouse: the checkpoint was trained on 'probe'"):
        run_transfer(
            TransferArgs(
                checkpoint=subset_run.run_dir, env="greenhouse", run_dir=str(tmp_path / "x")
            ),
            log=lambda *a: None,
        )
