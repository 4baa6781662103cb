"""SCORE end to end on the probe env: it learns, masks never recompile, runs resume exactly,
bad checkpoints and NaN are reported, and the data-parallel epoch equals the single-device one."""

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.agents.replay import replay_sample, replay_sample_nstep
from score_jax.agents.sac.losses import actor_loss, critic_loss
from score_jax.core.spaces import CompositeSpace, SubSpace
from score_jax.run.build import build, restore_run
from score_jax.run.checkpoint import Checkpointer, CheckpointError, check_space_matches
from score_jax.run.driver import NonFiniteError, train
from score_jax.run.validate import UsageError
from tests.tiny import TINY_OFF_POLICY, TINY_SCORE, tiny_cli_args, tiny_config

pytestmark = pytest.mark.slow  # scheduled first (conftest)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """An uninterrupted tiny run (1000 steps, checkpoints every 400)."""
    run_dir = tmp_path_factory.mktemp("runs") / "uninterrupted"
    return train(tiny_config(run_dir), log=lambda *a: None).for_seed(0)


def _params(state):
    return jax.device_get((state.agent.actor, state.agent.critic, state.agent.log_alpha))


def test_run_writes_metrics_and_checkpoints(finished_run):
    rows = open(os.path.join(finished_run.run_dir, "metrics.csv")).read().splitlines()
    assert rows[0].startswith("env_steps,seed,updates") and len(rows) == 1 + 1000 // 200
    assert Checkpointer(finished_run.run_dir).latest_step() == 1000
    assert int(finished_run.state.updates) > 0


def test_update_does_not_recompile_when_masks_change(finished_run):
    """Agent validity, failed sub-spaces (batch.active) and the DropNode rate are array inputs."""
    algo, state = finished_run.algo.off_policy, finished_run.state
    traces = []

    def counted(agent, batch, key, hyper):
        traces.append(1)
        return algo.update(agent, batch, key, hyper)

    update = jax.jit(counted)
    batch = replay_sample(state.buffer, jax.random.PRNGKey(0), 64)
    for i, (valid, drop) in enumerate([([1, 1, 1], 0.1), ([1, 0, 1], 0.5), ([0, 1, 0], 0.0)]):
        agent = state.agent.replace(consts=state.agent.consts.replace(valid=jnp.array(valid, bool)))
        b = batch.replace(
            active=jax.random.bernoulli(jax.random.PRNGKey(i), 0.7, batch.active.shape)
        )
        new, metrics = update(
            agent, b, jax.random.PRNGKey(i), algo.hyper.replace(dropnode_prob=jnp.float32(drop))
        )
        assert np.isfinite(float(metrics["critic_loss"]))
    assert len(traces) == 1


def test_nstep_target_bootstraps_with_the_samples_discount(finished_run):
    """SCORE's critic loss reads an n-step sample's discount: a discount of 0 is a terminal
    step (no bootstrap), a discount of 1 is the one-step target, and the trainer's n-step
    sampling yields a finite loss."""
    nets, state = finished_run.algo.networks, finished_run.state.agent
    hyper = finished_run.algo.off_policy.hyper
    n_envs = finished_run.config.off_policy.num_envs
    buffer = finished_run.state.buffer
    batch = replay_sample(buffer, jax.random.PRNGKey(0), 64)
    mask = jnp.ones((64, 3), bool)
    loss = jax.jit(
        lambda b: critic_loss(
            state.critic, state, b, mask, jax.random.PRNGKey(1), hyper, nets.policy_fn, nets.q_fn
        )[0]
    )
    ones, zeros = jnp.ones(64), jnp.zeros(64)
    np.testing.assert_allclose(loss(batch.replace(discount=ones)), loss(batch), rtol=1e-6)
    np.testing.assert_allclose(
        loss(batch.replace(discount=zeros)), loss(batch.replace(terminal=ones)), rtol=1e-6
    )
    assert not np.isclose(loss(batch.replace(discount=zeros)), loss(batch))
    three = replay_sample_nstep(buffer, jax.random.PRNGKey(2), 64, 3, n_envs, hyper.gamma)
    assert np.isfinite(float(loss(three))) and float(jnp.min(three.discount)) < 1.0
    from score_jax.run.trainer import Trainer  # the option reaches the trainer's updates

    cfg = dataclasses.replace(finished_run.config.off_policy, n_step=3, learning_starts=0)
    trainer = Trainer(finished_run.env, finished_run.algo.off_policy, cfg, finished_run.agent_index)
    new, metrics = trainer.epoch(trainer.init(jax.random.PRNGKey(3)), hyper)
    assert int(new.updates) > 0 and bool(metrics.finite)


def test_masked_agent_gets_no_actor_gradient(finished_run):
    """An agent masked out of the critic (failed / dropped / invalid) gets exactly zero actor
    gradient."""
    nets, state = finished_run.algo.networks, finished_run.state
    batch = replay_sample(state.buffer, jax.random.PRNGKey(0), 64)
    mask = jnp.broadcast_to(jnp.array([True, False, True]), (64, 3))
    loss = lambda p: actor_loss(
        p, state.agent, batch, mask, jax.random.PRNGKey(0), nets.policy_fn, nets.q_fn
    )[0]
    grads = jax.jit(jax.grad(loss))(state.agent.actor)
    per_agent = np.max(
        np.stack(
            [np.abs(np.asarray(g)).reshape(3, -1).max(axis=1) for g in jax.tree.leaves(grads)]
        ),
        axis=0,
    )
    assert per_agent[1] == 0.0 and per_agent[0] > 0 and per_agent[2] > 0


def test_sigkill_then_resume_equals_uninterrupted(finished_run, tmp_path):
    run_dir = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": ROOT}
    # stderr to a file, not an unread pipe: XLA logs a few kB per persistent-cache hit, and a
    # full pipe would block the child before its first checkpoint
    stderr = open(tmp_path / "stderr.txt", "w+")
    proc = subprocess.Popen(
        [sys.executable, "train.py", *tiny_cli_args(run_dir)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=stderr,
        stdin=subprocess.DEVNULL,
    )
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None:
        steps = (
            [d for d in os.listdir(run_dir / "checkpoints")]
            if (run_dir / "checkpoints").exists()
            else []
        )
        if any(d.isdigit() for d in steps):
            break
        time.sleep(0.2)
    assert proc.poll() is None, (
        f"train.py ended before it could be killed: {open(stderr.name).read()[-2000:]}"
    )
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    stderr.close()
    killed_at = Checkpointer(str(run_dir)).latest_step()
    assert killed_at is not None and killed_at < 1000
    out = subprocess.run(
        [sys.executable, "train.py", "--resume", str(run_dir), "--quiet"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert f"resumed {run_dir} at env step {killed_at}" in out.stdout
    resumed = restore_run(str(run_dir), log=lambda *a: None).for_seed(0)
    assert int(resumed.state.env_steps) == 1000
    jax.tree.map(np.testing.assert_array_equal, _params(resumed.state), _params(finished_run.state))
    rows = open(run_dir / "metrics.csv").read().splitlines()
    assert len(rows) == 1 + 1000 // 200  # rows after the checkpoint were not duplicated


def test_corrupted_checkpoints_give_clear_error(finished_run, tmp_path):
    """Every checkpoint corrupted (one corrupted checkpoint falls back to an older one:
    tests/test_checkpoint_faults.py)."""
    run_dir = tmp_path / "corrupt"
    shutil.copytree(finished_run.run_dir, run_dir)
    for step in Checkpointer(str(run_dir)).all_steps():
        for root, _, files in os.walk(run_dir / "checkpoints" / str(step) / "state"):
            for f in files:
                path = os.path.join(root, f)
                if os.path.getsize(path) > 64:
                    with open(path, "r+b") as fh:
                        fh.truncate(16)
    with pytest.raises(CheckpointError, match="no usable checkpoint.*could not be restored"):
        restore_run(str(run_dir), log=lambda *a: None)


def test_checkpoint_for_another_space_is_refused(finished_run):
    meta = Checkpointer(finished_run.run_dir).read_meta()
    check_space_matches(meta, "probe", finished_run.env.space)
    with pytest.raises(CheckpointError, match="trained on env 'probe', this run is 'greenhouse'"):
        check_space_matches(meta, "greenhouse", finished_run.env.space)
    other = CompositeSpace((SubSpace.continuous("a", 2, -1, 1, 0),))
    with pytest.raises(CheckpointError, match="does not match"):
        check_space_matches(meta, "probe", other)


def test_existing_run_dir_is_not_overwritten(finished_run):
    with pytest.raises(UsageError, match="already holds a run.*--resume"):
        train(tiny_config(finished_run.run_dir), log=lambda *a: None)


def test_nan_loss_stops_and_keeps_last_good_checkpoint(tmp_path):
    cfg = tiny_config(
        tmp_path / "nan",
        total_steps=800,
        checkpoint_every=200,
        off_policy=dataclasses.replace(TINY_OFF_POLICY, learning_starts=400),
        # finite (a NaN setting is refused up front), but the critic's targets overflow float32
        score=dataclasses.replace(TINY_SCORE, reward_scale=1e38),
    )
    with pytest.raises(NonFiniteError, match="last good checkpoint"):
        train(cfg, log=lambda *a: None)
    ckpt = Checkpointer(str(tmp_path / "nan"))
    assert (
        ckpt.latest_step() == 200
    )  # updates start in the second epoch (at 400 steps); it went NaN
    template = build(
        cfg, jax.random.PRNGKey(0), str(tmp_path / "nan"), restoring=True, log=lambda *a: None
    ).trainer.init(jnp.stack([jax.random.PRNGKey(1)]))
    state, _ = ckpt.restore(template)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(jax.device_get(state.agent.actor)))


def test_training_time_failures_go_through_the_failure_function(finished_run):
    """With train_failures=1 each collected step has exactly one failed agent, whose stored action
    is what the environment received (its default) and which the critic masks out."""
    from score_jax.run.trainer import Trainer

    cfg = dataclasses.replace(
        finished_run.config.off_policy,
        train_failures=1,
        train_failure_mode=0,
        learning_starts=10_000,
    )
    trainer = Trainer(finished_run.env, finished_run.algo.off_policy, cfg, finished_run.agent_index)
    state, _ = trainer.epoch(
        trainer.init(jax.random.PRNGKey(3)), finished_run.algo.off_policy.hyper
    )
    n = int(state.buffer.size)
    active = np.asarray(state.buffer.data.active[:n])
    np.testing.assert_array_equal(active.sum(axis=1), 2)
    default = np.asarray(finished_run.env.space.default_action())
    actions = np.asarray(state.buffer.data.action[:n])
    failed_rows, failed_agents = np.nonzero(~active)
    np.testing.assert_allclose(
        actions[failed_rows, failed_agents], default[failed_agents], atol=1e-6
    )


def test_exploration_noise_is_held_for_hold_steps(finished_run):
    """exploration_hold=3: an env redraws its exploration key only when its episode step is a
    multiple of 3, and with a held key its stochastic action is a function of the observation
    alone (the noise does not change)."""
    from score_jax.run.trainer import Trainer

    cfg = dataclasses.replace(finished_run.config.off_policy, exploration_hold=3)
    trainer = Trainer(finished_run.env, finished_run.algo.off_policy, cfg, finished_run.agent_index)
    state = trainer.init(jax.random.PRNGKey(5))
    t = jnp.arange(cfg.num_envs) % 4  # steps 0, 1, 2, 3, 0, ... into the envs' episodes
    state = state.replace(agent=finished_run.state.agent, env_state=state.env_state.replace(t=t))
    a1, k1 = trainer._explore(state, jax.random.PRNGKey(10))
    a2, k2 = trainer._explore(state, jax.random.PRNGKey(11))
    redraw = np.asarray(t % 3 == 0)
    kept = np.all(np.asarray(k1) == np.asarray(state.explore_keys), axis=1)
    np.testing.assert_array_equal(kept, ~redraw)
    np.testing.assert_array_equal(np.all(np.asarray(k1) == np.asarray(k2), axis=1), ~redraw)
    same = np.all(np.asarray(a1) == np.asarray(a2), axis=(1, 2))
    np.testing.assert_array_equal(same, ~redraw)  # held keys: same actions; redrawn: new noise
    one_step = Trainer(
        finished_run.env,
        finished_run.algo.off_policy,
        dataclasses.replace(cfg, exploration_hold=1),
        finished_run.agent_index,
    )
    assert one_step.hold == 1 and trainer.hold == 3
    with pytest.raises(ValueError, match="exploration_hold"):
        Trainer(
            finished_run.env,
            finished_run.algo.off_policy,
            dataclasses.replace(cfg, exploration_hold=-2),
            finished_run.agent_index,
        )


def test_exploration_shift_moves_each_subspace_as_a_whole_and_is_held(finished_run):
    """exploration_shift=0.5 with exploration_hold=3: on the probe (continuous a [2], b [3],
    discrete c [1]), every continuous column of an agent moves by one pre-tanh shift (the
    same for all its columns, its own for each agent and env), discrete and padded columns are
    untouched, and an env whose key is held keeps its shift."""
    from score_jax.run.trainer import Trainer

    base = dataclasses.replace(finished_run.config.off_policy, exploration_hold=3)
    make = lambda cfg: Trainer(
        finished_run.env, finished_run.algo.off_policy, cfg, finished_run.agent_index
    )
    plain = make(base)
    shifted = make(dataclasses.replace(base, exploration_shift=0.5))
    state = plain.init(jax.random.PRNGKey(5))
    t = jnp.arange(base.num_envs) % 4
    state = state.replace(agent=finished_run.state.agent, env_state=state.env_state.replace(t=t))
    a, _ = plain._explore(state, jax.random.PRNGKey(10))
    b, keys = shifted._explore(state, jax.random.PRNGKey(10))
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    continuous = shifted.continuous
    np.testing.assert_array_equal(continuous[:, :3], [[1, 1, 0], [1, 1, 1], [0, 0, 0]])
    np.testing.assert_array_equal(b[:, ~continuous], a[:, ~continuous])
    edge = 1 - 1e-6
    delta = np.arctanh(np.clip(b, -edge, edge)) - np.arctanh(np.clip(a, -edge, edge))
    for agent, cols in ((0, [0, 1]), (1, [0, 1, 2])):
        d = delta[:, agent, cols]  # [envs, columns]: one shift per env, equal over columns
        np.testing.assert_allclose(d, d[:, :1].repeat(len(cols), 1), atol=1e-3)
        assert np.all(np.abs(d[:, 0]) > 1e-3)
    assert np.unique(np.round(delta[:, 0, 0], 4)).size == base.num_envs  # per env
    assert not np.allclose(delta[:, 0, 0], delta[:, 1, 0], atol=1e-3)  # per agent
    held = np.asarray(t % 3 != 0)
    state = state.replace(explore_keys=keys)
    c, _ = shifted._explore(state, jax.random.PRNGKey(11))
    np.testing.assert_array_equal(np.asarray(c)[held], b[held].astype(np.float32))
