"""Issue 14 end to end on tiny runs: score-train on a registered environment the CLI knows
nothing about, with --track tensorboard / wandb (event files and the offline W&B run read
back), the header, the resolved config and provenance in config.json and the checkpoint;
score-eval's table and the greenhouse's season plot; --describe; the MP4 writer."""

import contextlib
import dataclasses
import glob
import importlib.util
import io
import json
import os
import time

import numpy as np
import pytest
import tyro

import envs
from envs.base import CompositeEnv
from envs.probe import make_probe
from score_jax.cli import eval as eval_cli
from score_jax.cli import train as train_cli
from score_jax.core.spaces import CompositeSpace
from score_jax.run.checkpoint import Checkpointer
from score_jax.run.config import TrainConfig
from score_jax.run.driver import train
from score_jax.run.writers import read_csv
from tests.test_writers import _tb_scalars, _wandb_history
from tests.tiny import tiny_cli_args, tiny_config

pytestmark = pytest.mark.slow  # scheduled first (conftest)

HAS_WANDB = importlib.util.find_spec("wandb") is not None
HAS_FFMPEG = importlib.util.find_spec("imageio_ffmpeg") is not None
HEADER_ITEMS = (
    "backend:",
    "devices:",
    "run dir:",
    "env:",
    "algo:",
    "seed:",
    "budget:",
    "evaluation:",
    "checkpoints:",
    "action repeat:",
    "updates:",
    "tracking:",
    "compile cache:",
)


# --- a registered environment the CLI knows nothing about -------------------------------------


class CustomEnv(CompositeEnv):
    """The probe's dynamics under another name, with units and without hints or references of
    its own (so the run takes ``EnvHints``' defaults)."""

    name = "tiny-custom"

    def __init__(self, **overrides):
        self.inner = make_probe(**overrides)
        self.space = CompositeSpace(
            tuple(dataclasses.replace(s, units="widgets") for s in self.inner.space.subspaces)
        )
        self.observation_size = self.inner.observation_size
        self.episode_length = self.inner.episode_length

    def reset(self, key):
        return self.inner.reset(key)

    def step(self, state, action):
        return self.inner.step(state, action)


def make_custom_env(**overrides) -> CustomEnv:
    return CustomEnv(**overrides)


def _train_cli(args: list[str]) -> int:
    return train_cli.main(tyro.cli(TrainConfig, args=args))


@pytest.fixture(scope="module")
def tracked_run(tmp_path_factory):
    """A tiny run through score-train's entry function on a registered environment the CLI
    knows nothing about (``CustomEnv``), with TensorBoard (and W&B offline, when installed)
    tracking; its directory and stdout."""
    envs.register("tiny-custom", make_custom_env)
    run_dir = str(tmp_path_factory.mktemp("runs") / "tracked")
    track = ["tensorboard", "wandb"] if HAS_WANDB else ["tensorboard"]
    mp = pytest.MonkeyPatch()
    mp.setenv("WANDB_MODE", "offline")
    mp.setenv("WANDB_API_KEY", "")
    mp.setenv("WANDB_BASE_URL", "http://127.0.0.1:9")  # a network call would fail
    stdout = io.StringIO()
    try:
        extra = ["--track", *track, "--robustness-seeds", "0", "--eval-episodes", "4"]
        with contextlib.redirect_stdout(stdout):
            args = tiny_cli_args(run_dir, total_steps=400)
            args[args.index("probe")] = "tiny-custom"
            rc = _train_cli(args + extra)
    finally:
        mp.undo()
    assert rc == 0, stdout.getvalue()
    return run_dir, stdout.getvalue().splitlines()


def test_header_comes_first_one_line_per_item(tracked_run):
    run_dir, lines = tracked_run
    header = lines[: len(HEADER_ITEMS)]
    assert [line.split(":")[0] + ":" for line in header] == list(HEADER_ITEMS)
    items = {line.split(":", 1)[0]: line.split(":", 1)[1].strip() for line in header}
    assert items["run dir"] == run_dir and items["algo"] == "score" and items["seed"] == "0"
    assert items["env"].startswith("tiny-custom: 3 sub-spaces, 6 action dims, 10-step episodes")
    assert items["budget"].startswith("400 decisions = 400 env steps")
    assert items["evaluation"] == "at the end only, 4 episodes"
    assert items["action repeat"] == "1 env step per decision"
    assert items["updates"].endswith("1-step TD targets")
    assert "tensorboard (" in items["tracking"]


def test_tensorboard_event_file_holds_the_logged_scalars(tracked_run):
    run_dir, _ = tracked_run
    rows = read_csv(os.path.join(run_dir, "metrics.csv"))
    scalars = _tb_scalars(os.path.join(run_dir, "tensorboard", "seed_0"))  # one run per seed
    assert len(rows) == 2  # two epochs of 200 decisions
    for name in ("episode_return", "reward_mean", "critic_loss", "updates"):
        logged = scalars[f"train/{name}"]
        want = [(int(r["env_steps"]), r[name]) for r in rows if not np.isnan(r[name])]
        assert [s for s, _ in logged] == [s for s, _ in want]
        np.testing.assert_allclose([v for _, v in logged], [v for _, v in want], rtol=1e-6)
    assert "train/eval_return" not in scalars  # NaN in every row: skipped


@pytest.mark.skipif(not HAS_WANDB, reason="wandb is not installed (pip install -e .[tracking])")
def test_wandb_offline_run_holds_the_logged_scalars(tracked_run):
    run_dir, _ = tracked_run
    files = glob.glob(os.path.join(run_dir, "wandb", "offline-run-*", "run-*.wandb"))
    assert len(files) == 1
    rows = read_csv(os.path.join(run_dir, "metrics.csv"))
    deadline = time.monotonic() + 30.0  # wandb's service process may still be writing
    while len(_wandb_history(files[0])) < len(rows) and time.monotonic() < deadline:
        time.sleep(0.2)
    history = _wandb_history(files[0])
    assert [h["env_steps"] for h in history] == [r["env_steps"] for r in rows]
    np.testing.assert_allclose(
        [h["seed_0/train/reward_mean"] for h in history],
        [r["reward_mean"] for r in rows],
        rtol=1e-6,
    )


def test_config_json_and_checkpoint_record_resolved_presets_and_provenance(tracked_run):
    run_dir, _ = tracked_run
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["eval_every"] is None and config["action_repeat"] is None  # the sentinels
    resolved = config["resolved"]
    assert config["env"] == "tiny-custom"
    assert resolved["total_steps"] == 400 and resolved["eval_every"] == 0  # EnvHints' default
    assert resolved["action_repeat"] == 1 and resolved["exploration_hold"] == 1
    assert resolved["checkpoint_every"] == 400 and resolved["env_steps"] == 400
    assert resolved["agents"] == ["a", "b", "c"] and resolved["reward_scale"] == 1.0
    assert resolved["default_prior"] == ["a", "b", "c"] and config["default_prior"] is True
    assert all(v is not None for v in resolved.values())
    prov = config["provenance"]
    assert {"jax", "flax", "brax", "mujoco"} <= {k for k, v in prov["packages"].items() if v}
    assert prov["device_kinds"] and prov["backend"] == "cpu"
    assert prov["git"] is None or len(prov["git"]["commit"]) == 40
    meta = Checkpointer(run_dir).read_meta()
    assert meta["provenance"]["packages"] == prov["packages"]


def test_score_eval_writes_the_table_of_a_saved_run(tracked_run, capsys):
    run_dir, _ = tracked_run
    args = eval_cli.EvalArgs(run_dir=run_dir, policy="best", episodes=4, render=True)
    assert eval_cli.main(args) == 0
    out = capsys.readouterr().out
    assert "kept no best policy" in out and "has no body to draw" in out
    folder = os.path.join(run_dir, "eval-last")  # no best kept: the last policy
    table = json.load(open(os.path.join(folder, "evaluation.json")))
    assert set(table["returns"]) == {"score (last, step 400)", "random", "default"}

    # the same seeds and policy as the end-of-run report
    end = json.load(open(os.path.join(run_dir, "evaluation.json")))
    assert table["returns"]["score (last, step 400)"] == end["returns"]["score"]
    assert table["returns"]["default"] == end["returns"]["default"]
    md = open(os.path.join(folder, "evaluation.md")).read()
    assert "| score (last, step 400) |" in md and "| random |" in md


def test_score_eval_plots_the_greenhouse_season_next_to_the_references(tmp_path, monkeypatch):
    """A greenhouse run of a few decisions (16-day seasons, decisions held 8 days, profit so the
    returns are not all 0), its best policy evaluated and its season plotted, next to the
    planned references (their search is ``test_greenhouse_references``'; here it is replaced by
    two fixed schedules, so what is checked is that they reach the table, the share column and
    the plot for the run's decision interval)."""
    from envs.greenhouse import references as refs

    asked = []

    def fixed_schedules(env, hold_days=1, **kw):
        asked.append(hold_days)
        space = env.space
        days = env.episode_length
        warm = space.from_physical(space.to_physical(space.default_action()).at[0, :].add(3.0))
        loop = np.stack([space.default_action()] * 8 + [warm] * (days - 8))
        return {"best constant": np.asarray(warm), "open-loop": loop}

    monkeypatch.setattr(refs, "reference_schedules", fixed_schedules)
    run_dir = str(tmp_path / "gh")
    cfg = tiny_config(
        run_dir,
        env="greenhouse",
        algo="isac",
        env_options=("season_days=16", "reward='profit'"),
        total_steps=200,
        checkpoint_every=200,
        eval_every=200,
        eval_episodes=1,
    )
    train(cfg, log=lambda *a: None)
    from score_jax.evaluation.saved_run import evaluate_saved_run

    out = evaluate_saved_run(run_dir, policy="best", log=lambda *a: None)
    label = "isac (best, step 200)"
    assert out["label"] == label and out["out_dir"] == os.path.join(run_dir, "eval-best")
    names = {label, "random", "default", "expert", "best constant", "open-loop"}
    assert set(out["rows"]) == names and set(asked) == {8}  # decisions held 8 days
    assert out["rows"]["open-loop"]["mean"] < 0  # a 16-day season's profit: no share given
    assert "share_of_open_loop" not in out["rows"][label]
    assert os.path.getsize(out["files"]["season"]) > 20_000
    md = open(out["files"]["markdown"]).read()
    assert "Season totals" in md and f"| {label} |" in md and "| expert |" in md
    # the plotted seasons hold decisions as the evaluation does: the same returns
    assert "| open-loop |" in md and "share of open-loop" in md  # (the column, empty here)
    for name in (label, "default", "expert", "best constant", "open-loop"):
        assert out["season"][name]["return"] == pytest.approx(out["rows"][name]["mean"], abs=1e-3)
        assert out["season"][name]["return"] != 0.0


def test_a_registered_environment_is_described_and_a_module_path_names_one(capsys):
    """(Training a registered environment from the CLI: ``tracked_run``.)"""
    envs.register("tiny-custom", make_custom_env)
    assert _train_cli(["--env", "tiny-custom", "--describe"]) == 0
    out = capsys.readouterr().out
    assert "environment 'tiny-custom': 3 sub-spaces" in out
    assert "widgets" in out and "budget 100000 decisions" in out  # EnvHints' defaults
    # "module:function" names an environment without registering it first
    assert _train_cli(["--env", "tests.test_cli_conventions:make_custom_env", "--describe"]) == 0
    assert "widgets" in capsys.readouterr().out
    assert _train_cli(["--env", "tests.nowhere:make", "--describe"]) == 1
    assert "cannot import the environment factory" in capsys.readouterr().err


# --- the Spider's video -----------------------------------------------------------------------


@pytest.mark.skipif(not HAS_FFMPEG, reason="imageio-ffmpeg is not installed (.[render])")
@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # imageio-ffmpeg reading back
def test_rollout_frames_become_a_gif_and_an_mp4(tmp_path):
    import imageio.v2 as iio

    from envs.spider.render import mp4_unavailable_reason, save_frames

    assert mp4_unavailable_reason() is None
    frames = [np.full((360, 480, 3), 10 * i, np.uint8) for i in range(12)]
    written = save_frames(frames, tmp_path, fps=20.0, png=False, gif=True, mp4=True)
    assert [p.name for p in written["gif"] + written["mp4"]] == ["rollout.gif", "rollout.mp4"]
    reader = iio.get_reader(written["mp4"][0])
    assert reader.get_meta_data()["size"] == (480, 360) and sum(1 for _ in reader) == 12


def test_without_ffmpeg_the_mp4_is_refused_with_the_install_hint(tmp_path, monkeypatch):
    import builtins

    from envs.spider import render

    real_import = builtins.__import__

    def no_ffmpeg(name, *args, **kwargs):
        if name == "imageio_ffmpeg":
            raise ImportError("No module named 'imageio_ffmpeg'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ffmpeg)
    assert 'pip install -e ".[render]"' in render.mp4_unavailable_reason()
    frames = [np.zeros((8, 8, 3), np.uint8)] * 2
    with pytest.raises(RuntimeError, match="imageio-ffmpeg"):
        render.save_frames(frames, tmp_path, png=False, gif=True, mp4=True)
    assert (tmp_path / "rollout.gif").exists()  # the GIF is written before


def test_messages_name_decisions_and_env_steps_apart(tmp_path):
    """With decisions held 8 env steps a log line says which count it gives (the greenhouse's
    evaluations used to print decisions as "env step"); with one step per decision the two
    counts are the same and the line says "env step"."""
    from score_jax.run.recorder import RunRecorder, step_label

    assert step_label(400) == "env step 400"
    assert step_label(16_000, 8) == "decision 16000 (env step 128000)"
    logs: list[str] = []
    recorder = RunRecorder(
        str(tmp_path),
        ["wall_s", "eval_return"],
        total=40,
        quiet=True,
        meta={},
        keep_best=False,
        seeds=(0, 1),
        log=logs.append,
        action_repeat=8,
    )
    recorder.record(20, [{"eval_return": 1.0}, {"eval_return": 3.0}], None)
    recorder.close()
    assert logs and logs[-1].startswith("decision 20 (env step 160): evaluation mean 2.0 over 2")
