"""Bad inputs to score-train, score-transfer and score-robustness are refused before any work:
every problem at once, one ``error:`` line each, exit status 2, no traceback, and nothing created
on a path that is only read. Environment options are typed against the environment's config."""

import dataclasses
import os
import subprocess
import sys
from typing import Literal

import numpy as np
import pytest
import tyro

import envs
from envs.base import parse_option
from score_jax.cli import robustness as robustness_cli
from score_jax.cli import train as train_cli
from score_jax.cli import transfer as transfer_cli
from score_jax.cli.robustness import RobustnessArgs
from score_jax.evaluation.transfer import TransferArgs
from score_jax.run import driver
from score_jax.run import validate as validate_module
from score_jax.run.checkpoint import Checkpointer, dump_json
from score_jax.run.config import TrainConfig, from_saved, to_dict

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture
def no_work(monkeypatch):
    """Building a run (networks, ASRL) or restoring one fails the test: refusals come first."""

    def refuse(*args, **kwargs):
        raise AssertionError("a run was built before the configuration was refused")

    monkeypatch.setattr(driver, "build", refuse)
    monkeypatch.setattr("score_jax.evaluation.transfer.restore_run", refuse)
    monkeypatch.setattr("score_jax.cli.robustness.restore_run", refuse)


@pytest.fixture
def run_with_checkpoint(tmp_path):
    """A directory that holds a run: a config.json of the probe and one committed checkpoint."""
    run_dir = tmp_path / "held"
    cfg = TrainConfig(env="probe", run_dir=str(run_dir), quiet=True)
    ckpt = Checkpointer(str(run_dir))
    ckpt.save(200, {"x": np.zeros(3, np.float32)}, {"env": "probe", "config": {}})
    ckpt.close()
    dump_json(str(run_dir / "config.json"), {**to_dict(cfg), "resolved": {"total_steps": 4000}})
    return run_dir


def _train(args, capsys):
    code = train_cli.main(tyro.cli(TrainConfig, args=args))
    err = capsys.readouterr().err
    return code, [line for line in err.splitlines() if line.strip()]


# (command-line arguments, a problem the one-line error must name); the defect numbers
BAD_TRAIN_INPUTS = [
    (["--total-steps", "-5"], "--total-steps -5: must be >= 1"),  # 1
    (
        ["--total-steps", "800", "--off-policy.replay-capacity", "64", "--off-policy.batch-size"]
        + ["128"],
        "the buffer could never hold a batch",
    ),  # 2
    (["--off-policy.num-envs", "0"], "--off-policy.num-envs 0: must be >= 1"),  # 3
    (["--env-options", "episode_length=maybe"], "expected an integer, got 'maybe'"),  # 4
    (["--env-options", "episode_length=1", "episode_length=2"], "given twice"),
    (["--env-options", "horizon=3"], "unknown probe env option 'horizon'"),
    (["--resume", "{tmp}/typo"], "no such directory"),  # 7
    (["--subspaces", ",,,"], "empty sub-space name"),  # 9
    (["--subspaces", "a,x"], "unknown sub-space(s) x"),
    (["--algo", "nope"], "unknown algorithm"),
    (["--score.gamma", "nan"], "--score.gamma nan: must be a finite number"),
    (["--marl.tau", "2"], "--marl.tau 2.0: must be in (0, 1]"),
    (["--score.critic-pessimism", "1.5"], "--score.critic-pessimism 1.5: must be in [0, 1]"),
    (["--render"], "--render needs a MuJoCo environment"),
    (["--total-steps", "100"], "before its first gradient update"),
    (["--off-policy.train-failures", "3"], "must be below the 3 controlled sub-spaces"),
    (["--seed", "-1"], "--seed -1: must be in 0.."),
    (["--algo", "sac", "--single.sac.min-replay-size", "5000"], "min-replay-size 5000"),
    (["--algo", "ppo", "--single.num-envs", "3"], "must be a multiple of --single.num-envs 3"),
    (["--num-processes", "2"], "--num-processes needs --distributed"),
    (["--distributed", "--num-processes", "2", "--process-id", "2"], "process id must be 0 .. 1"),
]


@pytest.mark.parametrize("args,problem", BAD_TRAIN_INPUTS, ids=[a[0] for a, _ in BAD_TRAIN_INPUTS])
def test_bad_train_input_is_refused_before_any_work(args, problem, tmp_path, capsys, no_work):
    run_dir = tmp_path / "run"
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    code, lines = _train(["--env", "probe", "--run-dir", str(run_dir), *args], capsys)
    assert code == 2, lines
    assert lines and all(line.startswith("error: ") for line in lines), lines
    assert any(problem in line for line in lines), lines
    assert not run_dir.exists() and not (tmp_path / "typo").exists()


def test_greenhouse_options_are_typed(capsys, no_work, tmp_path):
    """``discrete_hours=false`` is False (was the truthy string 'false'), ``=maybe`` an error; a
    missing weather file is an error line, not a FileNotFoundError traceback (defects 4, 5)."""
    code, lines = _train(
        ["--run-dir", str(tmp_path / "gh"), "--env-options", "discrete_hours=maybe"], capsys
    )
    assert code == 2 and "discrete_hours: expected true or false, got 'maybe'" in lines[0]
    code, lines = _train(
        ["--run-dir", str(tmp_path / "gh"), "--env-options", "weather_path=/nonexistent.epw"],
        capsys,
    )
    assert code == 2 and "weather file not found" in lines[0] and len(lines) == 1
    for text, value in [("false", False), ("FALSE", False), ("0", False), ("no", False)] + [
        ("True", True),
        ("yes", True),
        ("1", True),
    ]:
        cfg = TrainConfig(env_options=(f"discrete_hours={text}", "reward=profit"))
        assert cfg.env_overrides() == {"discrete_hours": value, "reward": "profit"}
    env = envs.make(
        "greenhouse", **TrainConfig(env_options=("discrete_hours=false",)).env_overrides()
    )
    assert env.config.discrete_hours is False
    assert all(s.kind == "continuous" for s in env.space.subspaces)


def test_option_values_parse_against_their_annotation():
    assert parse_option("(0.1, 0.9)", tuple[float, float]) == (0.1, 0.9)
    assert parse_option("0.1,0.9", tuple[float, float]) == (0.1, 0.9)
    assert parse_option("front_left,back_right", tuple[str, ...] | None) == (
        "front_left",
        "back_right",
    )
    assert parse_option("none", str | None) is None
    assert parse_option("'a.epw'", str | None) == "a.epw"
    assert parse_option("mean", Literal["attention", "mean"]) == "mean"
    for text, tp in [
        ("nan", float),
        ("inf", float),
        ("1.5", int),
        ("maybe", bool),
        ("median", Literal["attention", "mean"]),
        ("0.1,0.2,0.3", tuple[float, float]),
    ]:
        with pytest.raises(ValueError, match="expected"):
            parse_option(text, tp)
    values, problems = envs.parse_options(
        "spider", ["healthy_z_range=0.1,0.9", "physics.limits=no", "legs=front_left,front_right"]
    )
    assert problems == []
    assert values == {
        "healthy_z_range": (0.1, 0.9),
        "physics.limits": False,
        "legs": ("front_left", "front_right"),
    }


def test_every_problem_is_reported_at_once(capsys, no_work, tmp_path):
    code, lines = _train(
        ["--env", "probe", "--run-dir", str(tmp_path / "r"), "--total-steps", "-5"]
        + ["--off-policy.num-envs", "0", "--subspaces", ",,,", "--env-options", "x"],
        capsys,
    )
    assert code == 2 and len(lines) == 4, lines
    assert all(line.startswith("error: ") for line in lines)


def test_run_dir_holding_a_run_and_device_split_are_refused_up_front(
    run_with_checkpoint, monkeypatch, capsys, no_work
):
    """Both came only after ASRL (about a minute at default settings) before (defect 10)."""
    monkeypatch.setattr(validate_module.jax, "device_count", lambda: 3)
    code, lines = _train(["--env", "probe", "--run-dir", str(run_with_checkpoint)], capsys)
    assert code == 2
    text = "\n".join(lines)
    assert f"already holds a run (checkpoint at step 200); pass --resume {run_with_checkpoint}" in (
        text
    )
    assert "--off-policy.num-envs 8 must be a multiple of the 3 devices" in text
    assert "--off-policy.batch-size 128 must be a multiple of the 3 devices" in text


def test_resume_conflicts_and_short_budgets_are_refused(run_with_checkpoint, capsys, no_work):
    """``--resume`` keeps the saved configuration: a differing option is named, a budget at or
    below the checkpoint's step is refused (defect 6)."""
    code, lines = _train(
        ["--resume", str(run_with_checkpoint), "--seed", "3", "--off-policy.batch-size", "64"]
        + ["--total-steps", "200"],
        capsys,
    )
    assert code == 2, lines
    text = "\n".join(lines)
    assert "--seed 3 conflicts with the resumed run's 0" in text
    assert "--off-policy.batch-size 64 conflicts with the resumed run's 128" in text
    assert "--total-steps 200: the run has already done 200 decisions" in text


def test_transfer_and_robustness_refuse_bad_inputs_and_create_nothing(
    run_with_checkpoint, tmp_path, capsys, no_work
):
    typo = tmp_path / "typo"
    assert transfer_cli.main(TransferArgs(checkpoint=str(typo))) == 2
    assert "--checkpoint" in capsys.readouterr().err and not typo.exists()
    assert robustness_cli.main(RobustnessArgs(run_dir=str(typo), seeds=0)) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "no such directory" in err[0] and "--seeds 0" in err[1]
    assert not typo.exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert robustness_cli.main(RobustnessArgs(run_dir=str(empty))) == 2
    assert "no run there" in capsys.readouterr().err
    assert not (empty / "checkpoints").exists()


def test_transfer_names_missing_subspaces(tmp_path, capsys, no_work):
    """A run trained on ``a`` transferred to ``b,c`` names ``a`` (was the index ``[0]``), and
    ``,,,`` is refused instead of meaning every sub-space (defect 9)."""
    run_dir = tmp_path / "src"
    cfg = TrainConfig(env="probe", run_dir=str(run_dir), subspaces="a", quiet=True)
    _saved_run(run_dir, cfg)
    assert transfer_cli.main(TransferArgs(checkpoint=str(run_dir), subspaces="b,c")) == 2
    err = capsys.readouterr().err
    assert "leaves out the trained sub-space(s) a" in err and "[0]" not in err
    assert transfer_cli.main(TransferArgs(checkpoint=str(run_dir), subspaces=",,,")) == 2
    assert "empty sub-space name" in capsys.readouterr().err
    assert transfer_cli.main(TransferArgs(checkpoint=str(run_dir), subspaces="a")) == 2
    assert "no new sub-space" in capsys.readouterr().err
    assert not (tmp_path / "src-transfer").exists()


def _saved_run(run_dir, cfg: TrainConfig) -> None:
    """A finished run as the transfer checks read it: one checkpoint and its config.json."""
    ckpt = Checkpointer(str(run_dir))
    ckpt.save(200, {"x": np.zeros(3, np.float32)}, {"env": "probe"})
    ckpt.close()
    dump_json(str(run_dir / "config.json"), to_dict(cfg))


def test_new_actor_prior_is_refused_for_a_fixed_width_baseline(tmp_path, no_work):
    """A fixed-width run has no new actors to start at their defaults: --new-actor-prior is
    refused with the reason for a PPO run and accepted for a SCORE run."""
    refused = {}
    for algo in ("ppo", "score"):
        run_dir = tmp_path / algo
        cfg = TrainConfig(env="probe", algo=algo, run_dir=str(run_dir), subspaces="a,b")
        _saved_run(run_dir, cfg)
        args = TransferArgs(checkpoint=str(run_dir), new_actor_prior=True)
        problems = validate_module.validate_transfer_args(args)
        refused[algo] = [p for p in problems if p.startswith("--new-actor-prior")]
    assert len(refused["ppo"]) == 1 and "fixed-width baseline" in refused["ppo"][0]
    assert refused["score"] == []


def test_freeze_critic_encoder_needs_a_score_critic_with_encoders(tmp_path, no_work):
    """--freeze-critic-encoder is accepted for a SCORE run (its critic owns encoders by
    default), refused with the reason for one whose critic reads the frozen HVAE and for a
    baseline."""
    refused = {}
    runs = (("score", "score", True), ("frozen", "score", False), ("isac", "isac", True))
    for name, algo, own in runs:
        run_dir = tmp_path / name
        cfg = TrainConfig(env="probe", algo=algo, run_dir=str(run_dir), subspaces="a,b")
        critic = dataclasses.replace(cfg.score.critic, finetune_asrl=own)
        cfg = dataclasses.replace(cfg, score=dataclasses.replace(cfg.score, critic=critic))
        _saved_run(run_dir, cfg)
        args = TransferArgs(checkpoint=str(run_dir), freeze_critic_encoder=True)
        problems = validate_module.validate_transfer_args(args)
        refused[name] = [p for p in problems if p.startswith("--freeze-critic-encoder")]
    assert refused["score"] == []
    assert len(refused["frozen"]) == 1 and "no encoders of its own" in refused["frozen"][0]
    assert len(refused["isac"]) == 1 and "'isac'" in refused["isac"][0]


def test_command_lines_exit_2_without_traceback(tmp_path):
    """The real processes: train.py, transfer.py and score-robustness."""
    env = {**os.environ, "PYTHONPATH": ROOT}
    typo = tmp_path / "typo"
    commands = [
        ["train.py", "--env", "probe", "--total-steps", "-5", "--run-dir", str(tmp_path / "r")],
        ["transfer.py", "--checkpoint", str(typo)],
        ["-m", "score_jax.cli.robustness", "--run-dir", str(typo)],
    ]
    for command in commands:
        out = subprocess.run(
            [sys.executable, *command],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            stdin=subprocess.DEVNULL,
            timeout=300,
        )
        lines = [line for line in out.stderr.splitlines() if line.startswith("error: ")]
        assert out.returncode == 2, out.stderr[-2000:]
        assert "Traceback" not in out.stderr and lines, out.stderr[-2000:]
    assert len(lines) == 1 and not typo.exists() and not (tmp_path / "r").exists()


def test_resume_of_a_brax_run_is_refused_up_front(tmp_path, capsys, no_work):
    run_dir = tmp_path / "ppo"
    ckpt = Checkpointer(str(run_dir))
    ckpt.save(2560, {"x": np.zeros(3, np.float32)}, {"env": "probe"})
    ckpt.close()
    dump_json(str(run_dir / "config.json"), to_dict(TrainConfig(env="probe", algo="ppo")))
    code, lines = _train(["--resume", str(run_dir)], capsys)
    assert code == 2 and len(lines) == 1 and "cannot be continued exactly" in lines[0]


def test_saved_config_keeps_the_defaults_it_ran_with():
    """A run saved before a default changed rebuilds as it ran: a missing key reads the old
    value (CHANGED_DEFAULTS), a present one its own, and a current save round-trips."""
    saved = to_dict(TrainConfig())
    assert from_saved(saved) == TrainConfig()
    assert TrainConfig().score.critic.finetune_asrl  # the current default ...
    del saved["score"]["critic"]["finetune_asrl"]
    old = from_saved(saved)
    assert old.score.critic.finetune_asrl is False  # ... and what a run saved before it ran
    assert "finetune_asrl" not in saved["score"]["critic"]  # the caller's dict is untouched
    assert old.score.init_alpha == TrainConfig().score.init_alpha  # saved keys are kept
    # options taken from the environment's hints are pinned to the values they resolved to then
    saved = {**to_dict(TrainConfig()), "resolved": {"exploration_hold": 1, "action_repeat": 8}}
    assert saved["off_policy"]["exploration_hold"] is None and saved["action_repeat"] is None
    assert from_saved(saved).off_policy.exploration_hold == 1
    assert from_saved(saved).action_repeat == 8
    saved["off_policy"]["exploration_hold"] = 4  # ... and one given on the command line kept
    assert from_saved(saved).off_policy.exploration_hold == 4
    # a run saved when the update schedule was a plain default of 2 stored it, so it keeps it
    saved["off_policy"]["updates_per_step"] = 2
    assert from_saved(saved).off_policy.updates_per_step == 2
    saved["off_policy"]["updates_per_step"] = None  # a hinted one resumes as it resolved
    saved["resolved"]["updates_per_step"] = 1
    assert from_saved(saved).off_policy.updates_per_step == 1
    # runs saved before n-step returns trained one-step targets; hinted ones resume as resolved
    del saved["off_policy"]["n_step"]
    assert from_saved(saved).off_policy.n_step == 1
    saved["off_policy"]["n_step"] = None
    saved["resolved"]["n_step"] = 3
    assert from_saved(saved).off_policy.n_step == 3
