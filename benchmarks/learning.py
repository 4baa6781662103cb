"""The project's learning targets in one command: SCORE on the greenhouse (the main job, K seeds,
and daily decisions on the same simulated days) and on the Spider (against brax's SAC and the
hand-made gait), each next to its reference policies, with statistics over seeds and every
target printed as met / not met.

    python benchmarks/learning.py                               # both envs, full budgets
    python benchmarks/learning.py --out benchmarks/results      # the committed results + GIF
    python benchmarks/learning.py --envs greenhouse --no-daily  # the main job's K seeds only
    python benchmarks/learning.py --envs greenhouse --no-main   # the daily run's K seeds only
    python benchmarks/learning.py --envs greenhouse --seeds 3 --env-steps 160000
    python benchmarks/learning.py --quick                       # the pipeline, small (minutes)
    python benchmarks/learning.py --base.score.critic.no-asrl   # any train.py setting, every run

Greenhouse (``--seeds`` K seeds, one run of ``--num-seeds K``):
- references for each decision interval, evaluated on the learned policies' first evaluation
  seed: default setpoints, random, the expert heuristic and (unless
  ``--no-planned-references``) the planned best constant and open-loop schedules
  (``envs/greenhouse/references.py``; cached in ~/.cache/score-jax/references);
- SCORE with the main job's settings (``TrainConfig()``: decisions held 8 days, 144k decisions
  = 1.152 M simulated days per seed; ``--env-steps`` days instead): each seed's final and
  best-evaluated policy, its training stability (``evaluation/stability.py``: the lowest
  moving-mean training return after first beating the default setpoints), the final returns
  as shares of the open-loop schedule, IQM / mean / median with 95% stratified-bootstrap
  intervals over seeds, and the wall time of the K-seed run;
- targets: every seed's final policy above the expert; the IQM of the final policies at least
  the best constant schedule; every seed held; the K-seed run within 20 minutes (measured and
  reported, not asserted);
- daily decisions (``action_repeat=1``, unless ``--no-daily``) on the same simulated days, with
  ``--daily-num-envs`` environments (default 64: as many vectorised steps and gradient updates
  as the 8-day run with 8), ``--daily-replay-capacity`` transitions and the same discount per
  simulated day (gamma^(1/8) per decision); target: IQM above the
  default setpoints.

Spider (``--spider-seeds`` seeds, ``--spider-env-steps`` steps each): references standing still
(``default``), random and the open-loop gait (``envs/spider/gait.py``), with their forward speed;
SCORE and brax's SAC with the same budget and seeds: final and best returns, forward speed of
the final policy (x displacement / simulated time, m/s), wall time; targets: SCORE IQM >= 2000,
SCORE above SAC (IQMs and the probability of improvement), SCORE above the gait. ``--gif``
renders the best SCORE seed's final policy (``docs/spider_learned_gait.gif`` when ``--out`` is
benchmarks/results, else into ``--out``; a warning if rendering fails).

Per environment it writes to ``--out``: ``learning_<env>.json`` (every number, the curves, the
command, commit, machine and date), ``learning_<env>.md`` (references, per-seed values, IQM /
mean [95% CI], targets met / not met, provenance) and ``learning_<env>.png`` (deterministic
evaluations against environment steps, i.e. simulated days on the greenhouse, not decisions:
the mean over seeds with its 95% band, every seed faint, the references dashed; greenhouse: one
panel for 8-day and one for daily decisions).

Runs go to ``--work-dir/<env>/<run>/s0-<K-1>``; a run whose ``result.json`` matches its settings
is reused (``benchmarks/compare.py``'s cache), so a killed invocation continues with the run it
stopped in (that run starts over). Each step prints its wall time. ``--quick`` caps everything
(2 seeds, 16k simulated days on the greenhouse, 10k Spider steps, 300 ASRL steps, 2 episodes
per evaluation, 4 evaluations per run): it checks the pipeline, not the targets.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import shlex
import sys
import tempfile
import time
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
import tyro

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import envs  # noqa: E402
from benchmarks import compare  # noqa: E402
from envs.wrappers import unwrapped, with_action_repeat  # noqa: E402
from score_jax import registry  # noqa: E402
from score_jax.core.failures import fail_batch  # noqa: E402
from score_jax.core.spaces import agents_to_env_action, pad_width  # noqa: E402
from score_jax.evaluation.curves import plot_band, read_rows  # noqa: E402
from score_jax.evaluation.stability import lowest_after_exceeding  # noqa: E402
from score_jax.evaluation.stats import format_interval, probability_of_improvement  # noqa: E402
from score_jax.run.best_policy import has_best, restore_best  # noqa: E402
from score_jax.run.build import resolve_agent_index, restore_run, with_best_policy  # noqa: E402
from score_jax.run.compile_cache import enable_compile_cache  # noqa: E402
from score_jax.run.config import TrainConfig  # noqa: E402
from score_jax.run.episodes import reference_policies  # noqa: E402
from score_jax.run.provenance import provenance  # noqa: E402

# Spider steps per seed by default (the learning issue's budget); the greenhouse default is the
# main job's (TrainConfig's presets: 144k decisions held 8 days = 1.152 M simulated days).
SPIDER_STEPS = 500_000
QUICK_BUDGET = {"greenhouse": 16_000, "spider": 10_000}
QUICK_SEEDS = 2
QUICK_ASRL_STEPS = 300
QUICK_EPISODES = 2
QUICK_EVAL_POINTS = 4
WALL_TARGET_S = 20 * 60  # the greenhouse K-seed run (measured and reported, not asserted)
SPIDER_IQM_TARGET = 2000.0
GIF_NAME = "spider_learned_gait.gif"
COMMITTED_OUT = os.path.join(ROOT, "benchmarks/results")  # where the committed results go
COMMITTED_GIF = os.path.join(ROOT, "docs", GIF_NAME)
LABELS = {"score": "SCORE", "sac": "SAC (brax)"}
REFERENCE_LABELS = {
    "default": "default setpoints",
    "random": "random",
    "expert": "expert heuristic",
    "best constant": "best constant schedule",
    "open-loop": "open-loop schedule",
    "gait": "open-loop gait",
}
SPIDER_REFERENCE_LABELS = {**REFERENCE_LABELS, "default": "standing still (zero action)"}
GIF_WIDTH = 320  # pixels; the rendered frames are 480 x 360
GIF_EVERY = 2  # keep every 2nd frame (10 frames per simulated second)


@dataclasses.dataclass(frozen=True)
class LearningArgs:
    """Reproduce the learning targets (greenhouse and Spider): references, SCORE over seeds,
    targets met / not met; write JSON, markdown and learning curves."""

    envs: tuple[Literal["greenhouse", "spider"], ...] = ("greenhouse", "spider")
    """Parts to run."""
    quick: bool = False
    """Cap everything (2 seeds, 16k simulated days, 10k Spider steps, 300 ASRL steps, 2 episodes
    per evaluation, 4 evaluations per run): checks the pipeline in minutes, not the targets."""
    seeds: int = 5
    """Greenhouse seeds (first-seed .. first-seed + seeds - 1), trained in one run per decision
    interval (``--num-seeds``)."""
    first_seed: int = 0
    """First greenhouse seed: 6 with ``--seeds 6`` trains seeds 6..11, a second draw of the same
    settings (in its own run directory, ``s6-11``; the references use this seed's evaluation
    key)."""
    env_steps: int = 0
    """Simulated days per greenhouse seed, for the 8-day and the daily run alike; 0 = the main
    job's (the presets of ``--base``: 144k decisions x 8 days = 1.152 M)."""
    daily: bool = True
    """Also train with daily decisions (``action_repeat=1``) on the same simulated days."""
    main: bool = True
    """Train the main job's decision interval; ``--no-main --daily`` trains only the daily run
    (both intervals' references are still evaluated; the main job's targets are then not
    checked)."""
    daily_num_envs: int = 64
    """Environments of the daily run (64: as many vectorised steps and gradient updates as the
    8-day run with 8)."""
    daily_replay_capacity: int = 400_000
    """Replay capacity of the daily run, in transitions."""
    daily_same_discount_per_day: bool = True
    """The daily run discounts each simulated day as the main run does (its gamma is the main
    run's gamma to the power 1/action repeat: 0.99 per 8 days = 0.99874 per day), so both weigh
    the season's late harvest alike; False keeps the main run's gamma per decision."""
    planned_references: bool = True
    """Evaluate the greenhouse's planned references (best constant and open-loop schedules for
    each decision interval; about a minute each the first time, then cached)."""
    spider_seeds: int = 3
    """Spider seeds, for SCORE and for brax's SAC (one run each)."""
    spider_env_steps: int = SPIDER_STEPS
    """Environment steps per Spider seed."""
    gif: bool = True
    """Render the best SCORE Spider seed's final policy to a GIF."""
    gif_out: str = ""
    """Where the GIF goes; empty = docs/spider_learned_gait.gif when --out is
    benchmarks/results, else <out>/spider_learned_gait.gif."""
    gif_steps: int = 200
    """Environment steps of the rendered episode (0.05 s each); the GIF keeps every 2nd frame at
    320 x 240 (about 35 kB a frame)."""
    eval_points: int = 0
    """Deterministic evaluations per run (curve points, and the best policy's candidates);
    0 = the environment's preset interval (greenhouse every 16k decisions of 8 days = 128k
    simulated days, Spider every 20k steps), at least 2 per run."""
    eval_episodes: int = 10
    """Episodes per evaluation, for the learned policies and the references alike."""
    out: str = os.path.join(ROOT, "runs", "benchmarks")
    """Where the JSON, markdown and figures go (the committed ones: --out benchmarks/results)."""
    work_dir: str = os.path.join(ROOT, "runs", "learning")
    """Where the runs go (reused when their settings match)."""
    base: TrainConfig = TrainConfig(robustness_seeds=0, quiet=True)
    """Settings shared by every run (e.g. --base.score.asrl-steps 500); its presets (budget,
    evaluation interval) are the default budget."""


def resolved(args: LearningArgs) -> LearningArgs:
    """``args`` with ``--quick``'s caps applied (unchanged without it)."""
    if not args.quick:
        return args
    base = args.base
    if base.score.asrl_steps > QUICK_ASRL_STEPS:
        base = dataclasses.replace(
            base, score=dataclasses.replace(base.score, asrl_steps=QUICK_ASRL_STEPS)
        )
    cap = lambda value, limit: min(value, limit) if value else limit
    return dataclasses.replace(
        args,
        seeds=min(args.seeds, QUICK_SEEDS),
        spider_seeds=min(args.spider_seeds, QUICK_SEEDS),
        env_steps=cap(args.env_steps, QUICK_BUDGET["greenhouse"]),
        spider_env_steps=cap(args.spider_env_steps, QUICK_BUDGET["spider"]),
        eval_points=args.eval_points or QUICK_EVAL_POINTS,
        eval_episodes=min(args.eval_episodes, QUICK_EPISODES),
        base=base,
    )


# --- episodes: returns and forward speed ---------------------------------------------------


def episodes(env, act_fn, key: jax.Array, n_episodes: int, agent_index) -> dict:
    """``n_episodes`` episodes of ``act_fn`` exactly as ``run.episodes.evaluate`` plays them (the
    same keys, no failures): ``{"returns", "lengths"}`` ``[E]`` and, when the environment reports
    ``metrics.x_position`` (Spider), ``"distance"`` (x displacement from the reset pose to the
    episode's last step, m) and ``"speed"`` (distance / simulated time, m/s)."""
    space = env.space
    agent_index = np.asarray(agent_index)
    controlled = np.zeros(space.n, bool)
    controlled[agent_index] = True
    key_reset, key_run = jax.random.split(key)
    state = jax.vmap(env.reset)(jax.random.split(key_reset, n_episodes))
    x_of = lambda s: getattr(s.metrics, "x_position", None)
    x0 = x_of(state)
    last = jnp.broadcast_to(space.default_action(), (n_episodes, space.n, space.max_dim))

    def step(carry, key_t):
        state, last, ret, alive, length, x_end = carry
        key_act, key_fail = jax.random.split(key_t)
        action = agents_to_env_action(space, act_fn(state, key_act), agent_index)
        applied, _ = fail_batch(space, action, last, key_fail, 0, 0, controlled)
        state = jax.vmap(env.step)(state, applied)
        ret = ret + alive * state.reward
        length = length + alive
        if x_end is not None:
            x_end = jnp.where(alive > 0, x_of(state), x_end)
        alive = alive * (1.0 - state.done)
        return (state, applied, ret, alive, length, x_end), None

    zeros = jnp.zeros(n_episodes)
    carry = (state, last, zeros, jnp.ones(n_episodes), zeros, x0)
    (_, _, ret, _, length, x_end), _ = jax.lax.scan(
        step, carry, jax.random.split(key_run, env.episode_length)
    )
    out = {"returns": ret, "lengths": length}
    if x0 is not None:
        seconds = length * env_seconds_per_step(env)
        out["distance"] = x_end - x0
        out["speed"] = out["distance"] / jnp.maximum(seconds, 1e-9)
    return out


def env_seconds_per_step(env) -> float:
    """Simulated seconds per step of ``env`` (its action repeat times the base env's ``dt``)."""
    base = unwrapped(env)
    return float(base.dt) * float(getattr(env, "repeat", 1))


def reports_position(env) -> bool:
    """Whether ``env``'s metrics hold ``x_position`` (the forward speed can be measured)."""
    state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    return hasattr(state.metrics, "x_position")


def gait_act_fn(env, agent_index, width: int):
    """The Spider's open-loop sinusoidal gait (``envs/spider/gait.py``) as a batched act function:
    the gait's action at the state's time ``t * dt``, restricted to the agents' sub-spaces and
    padded to ``width`` (as ``render.gait_rollout_qpos`` plays it)."""
    from envs.spider.gait import sinusoidal_gait  # deferred: the Spider's modules import mujoco

    base = unwrapped(env)
    idx = np.asarray(agent_index)

    def act(state, key):
        action = sinusoidal_gait(base.legs, base.space, state.t * base.dt)  # [E, n, max_dim]
        return pad_width(action[:, idx], width)

    return act


def _row(result: dict) -> dict:
    """Mean, std, min, max of an ``episodes`` result's returns (and mean speed / distance)."""
    r = np.asarray(result["returns"], float)
    row = {"mean": float(r.mean()), "std": float(r.std()), "min": float(r.min())}
    row["max"] = float(r.max())
    for name in ("speed", "distance"):
        if name in result:
            row[name] = float(np.mean(result[name]))
    return row


def references(cfg: TrainConfig, n_episodes: int, planned: bool) -> dict[str, dict]:
    """Every reference policy of ``cfg``'s environment and decision interval, over
    ``n_episodes`` episodes of the first seed's evaluation key (``Run.eval_keys``): random,
    default, the environment's scripted ones (greenhouse: expert), with ``planned`` the
    planned ones (greenhouse: best constant, open-loop) and on the Spider the open-loop gait.
    ``{name: {"mean", "std", "min", "max"(, "speed", "distance")}}``."""
    raw = envs.make(cfg.env, **cfg.env_overrides())
    env = with_action_repeat(raw, compare.action_repeat(cfg))
    idx = resolve_agent_index(env.space, cfg.agent_names())
    width = env.space.max_dim if cfg.action_width is None else cfg.action_width
    acts = dict(reference_policies(env, idx, width, planned))
    if hasattr(unwrapped(env), "legs"):
        acts["gait"] = gait_act_fn(env, idx, width)
    key = jax.random.PRNGKey(cfg.seed + 10_000)  # Run.eval_keys() of the first seed
    out = {}
    for name, act in acts.items():
        run = jax.jit(lambda k, act=act: episodes(env, act, k, n_episodes, idx))
        out[name] = _row(jax.device_get(run(key)))
    return out


def learned_report(run) -> dict:
    """What ``compare.run_full`` adds to a trained run's result: each seed's best-evaluated
    policy's mean return over the evaluation episodes (None without periodic evaluations) and
    the env step (decision) it was kept at; where the environment reports positions, each
    seed's final policy's forward ``speed`` (m/s) and ``distance`` (m), means over the same
    episodes."""
    n = run.config.eval_episodes
    out = {"best": None, "best_steps": None, "speed": None, "distance": None}
    if has_best(run.run_dir):
        _, meta = restore_best(run.run_dir, run.state.agent)
        best = with_best_policy(run, log=lambda *a: None).state.agent
        returns = np.asarray(run.evaluate(best, n).returns, float)
        out["best"] = returns.reshape(run.num_seeds, -1).mean(axis=1).tolist()
        out["best_steps"] = meta["best_steps"]
    if reports_position(run.env):

        def one(agent, key):
            return episodes(run.env, run.algo.policy(agent), key, n, run.agent_index)

        res = jax.device_get(jax.jit(jax.vmap(one))(run.state.agent, run.eval_keys()))
        out["speed"] = np.asarray(res["speed"], float).mean(axis=1).tolist()
        out["distance"] = np.asarray(res["distance"], float).mean(axis=1).tolist()
    return out


# --- runs ----------------------------------------------------------------------------------


def eval_interval(args: LearningArgs, base: TrainConfig, env_steps: int) -> int:
    """Environment steps between evaluations of a run of ``env_steps`` on ``base.env`` (0 = only
    at the end, when ``--base.eval-every 0``)."""
    repeat = compare.action_repeat(base)
    if args.eval_points:
        return max(repeat, env_steps // args.eval_points)
    every = base.eval_every
    if every is None:
        every = envs.make(base.env, **base.env_overrides()).hints.eval_every
    if not every:
        return 0
    return max(repeat, min(every * repeat, env_steps // 2))


def run_config(
    args: LearningArgs,
    base: TrainConfig,
    algo: str,
    name: str,
    seeds: int,
    env_steps: int,
    interval: int,
) -> TrainConfig:
    """One run (every seed in one program, ``compare.row_config``) of ``env_steps`` per seed on
    ``base.env``, evaluated every ``interval`` env steps, in ``<work-dir>/<env>/<name>/``."""
    cargs = compare.CompareArgs(
        seeds=seeds, env_steps=env_steps, eval_episodes=args.eval_episodes, base=base
    )
    first = args.first_seed if base.env == "greenhouse" else 0
    run_dir = os.path.join(args.work_dir, base.env, name, compare._seeds_dir(seeds, first))
    cfg = dataclasses.replace(
        compare.row_config(cargs, base.env, algo, run_dir=run_dir), seed=first
    )
    repeat = compare.action_repeat(base)
    # the planned references are this script's job (not part of a run's identity)
    return dataclasses.replace(cfg, eval_every=interval // repeat, planned_references=False)


def _csv_has(path: str, column: str) -> bool:
    if not os.path.exists(path):
        return False
    with open(path) as f:
        return column in f.readline().strip().split(",")


def summarise_run(res: dict, cfg: TrainConfig, refs: dict) -> dict:
    """One trained run (``compare.run_full``'s result with ``learned_report``) against the
    references of its decision interval: per-seed values and their statistics over seeds;
    every step count in environment steps (simulated days on the greenhouse)."""
    repeat = compare.action_repeat(cfg)
    report = res.get("report") or {}
    final = [float(x) for x in res["returns"]]
    best = report.get("best")  # None: the run kept no best policy (brax's SAC evaluates itself)
    out = {
        "algo": cfg.algo,
        "run_dir": cfg.run_dir,
        "seeds": list(range(cfg.seed, cfg.seed + cfg.num_seeds)),
        "action_repeat": repeat,
        "decisions": cfg.total_steps,
        "env_steps": cfg.total_steps * repeat,
        "num_envs": (
            cfg.off_policy.num_envs if registry.entry(cfg.algo).in_process else cfg.single.num_envs
        ),
        "replay_capacity": cfg.off_policy.replay_capacity,
        "eval_every_env_steps": (cfg.eval_every or 0) * repeat,
        "wall_s": res.get("wall_s"),
        "final": compare._summary(final),
        "best": None if best is None else compare._summary(best),
        "best_env_steps": [
            None if s is None else int(s) * repeat for s in (report.get("best_steps") or [])
        ],
        "curves": [
            {
                "seed": c["seed"],
                "env_steps": [int(s) * repeat for s in c["steps"]],
                "returns": c["returns"],
            }
            for c in res["curves"]
        ],
    }
    for name in ("speed", "distance"):
        if report.get(name) is not None:
            out[name] = compare._summary(report[name])
    top = refs.get("open-loop")
    if top is not None and top["mean"] > 0:
        out["share_of_open_loop"] = [x / top["mean"] for x in final]
        if best is not None:
            out["best_share_of_open_loop"] = [x / top["mean"] for x in best]
        out["final_percent_of_open_loop"] = compare._summary([100 * x / top["mean"] for x in final])
    csv_path = os.path.join(cfg.run_dir, "metrics.csv")
    if not registry.entry(cfg.algo).in_process and os.path.exists(csv_path):
        out["wall_s_per_seed"] = seed_walls(csv_path)
    if "default" in refs and _csv_has(csv_path, "episode_return"):
        rows = read_rows(csv_path)
        if any(r["episode_return"] not in ("", "nan") for r in rows):
            threshold = refs["default"]["mean"]
            stability = lowest_after_exceeding(csv_path, threshold)
            as_env = lambda v: None if v is None else v * repeat
            out["stability"] = {
                "threshold": threshold,
                "per_seed": {
                    str(seed): {
                        **s,
                        "first_above": as_env(s["first_above"]),
                        "lowest_at": as_env(s["lowest_at"]),
                    }
                    for seed, s in stability.items()
                },
            }
    return out


def seed_walls(csv_path: str) -> list[float]:
    """Training seconds of each seed of a run whose seeds trained one after another (brax's
    loops): the growth of ``metrics.csv``'s ``wall_s`` over each seed's rows (the run's set-up
    before the first row is not counted)."""
    last: dict[int, float] = {}
    for row in read_rows(csv_path):
        seed = int(float(row.get("seed", 0) or 0))
        last[seed] = max(last.get(seed, 0.0), float(row["wall_s"]))
    ends = [last[seed] for seed in sorted(last)]
    return [end - start for start, end in zip([0.0, *ends[:-1]], ends, strict=True)]


def _target(name: str, met, value: str) -> dict:
    """One target: ``met`` True / False, or None when it could not be measured."""
    return {"target": name, "met": None if met is None else bool(met), "value": value}


def _fmt(summary: dict, metric: str = "iqm", digits: int = 1) -> str:
    iv = summary["mean_ci"] if metric == "mean" else summary[metric]
    return format_interval(iv["value"], iv["lo"], iv["hi"], digits)


def _seconds(s: float | None) -> str:
    if s is None:
        return "not recorded"
    return f"{s:.0f} s ({s / 60:.1f} min)"


class Steps:
    """Progress lines ``[env i/n] what ... done (s; s in all)``."""

    def __init__(self, env: str, total: int):
        self.env, self.total, self.i, self.t0 = env, total, 0, time.time()

    def start(self, what: str) -> float:
        self.i += 1
        print(f"[{self.env} {self.i}/{self.total}] {what} ...", flush=True)
        return time.time()

    def done(self, t: float, what: str) -> None:
        now = time.time()
        print(
            f"[{self.env} {self.i}/{self.total}] {what} ({now - t:.0f} s; {now - self.t0:.0f} s "
            "in all)",
            flush=True,
        )

    def log(self, line: str) -> None:
        print(f"    {line}", flush=True)


def _train(steps: Steps, label: str, cfg: TrainConfig, errors: dict) -> dict | None:
    """``compare.run_full`` with ``learned_report``, between progress lines; a failure is kept
    in ``errors`` (the other parts go on)."""
    seeds = f"{cfg.num_seeds} seed{'s' if cfg.num_seeds > 1 else ''}"
    t = steps.start(f"{label}: {seeds} x {cfg.total_steps} decisions ({cfg.run_dir})")
    path = os.path.join(cfg.run_dir, "result.json")
    before = os.path.getmtime(path) if os.path.exists(path) else None
    try:
        res = compare.run_full(cfg, cfg.eval_episodes, report=learned_report, log=steps.log)
    except Exception as e:  # one failing run must not stop the others; it is reported
        errors[label] = f"{type(e).__name__}: {e}"
        steps.done(t, f"{label} FAILED ({type(e).__name__}: {str(e)[:200]})")
        return None
    finals = ", ".join(f"{x:.1f}" for x in res["returns"])
    reused = " (reused)" if before is not None and os.path.getmtime(path) == before else ""
    steps.done(
        t, f"{label}{reused}: final returns {finals}; trained in {_seconds(res.get('wall_s'))}"
    )
    return res


# --- greenhouse ----------------------------------------------------------------------------


def greenhouse_budget(args: LearningArgs) -> int:
    """Simulated days per greenhouse seed: ``--env-steps``, else the main job's (the presets of
    ``--base``: its decisions times its action repeat)."""
    base = dataclasses.replace(args.base, env="greenhouse")
    if args.env_steps:
        return args.env_steps
    preset = envs.make(base.env, **base.env_overrides()).hints.total_steps
    return (base.total_steps or preset) * compare.action_repeat(base)


def greenhouse_configs(args: LearningArgs) -> dict[str, TrainConfig]:
    """The greenhouse runs by label: ``"<k>-day"`` (``"8-day"`` by default), the main job's
    settings (``--base``, decisions held its action repeat of k days), and with
    ``--daily`` ``"daily"``: ``action_repeat=1``, ``--daily-num-envs`` environments,
    ``--daily-replay-capacity`` and the same discount per simulated day; both on
    ``greenhouse_budget`` simulated days per seed and evaluated every as many simulated days."""
    base = dataclasses.replace(args.base, env="greenhouse")
    budget = greenhouse_budget(args)
    interval = eval_interval(args, base, budget)
    main = f"{compare.action_repeat(base)}-day"
    out = {main: run_config(args, base, "score", "score", args.seeds, budget, interval)}
    if args.daily:
        off_policy = dataclasses.replace(
            base.off_policy,
            num_envs=args.daily_num_envs,
            replay_capacity=args.daily_replay_capacity,
        )
        daily = dataclasses.replace(base, action_repeat=1, off_policy=off_policy)
        if args.daily_same_discount_per_day:
            gamma = base.score.gamma ** (1.0 / compare.action_repeat(base))
            daily = dataclasses.replace(daily, score=dataclasses.replace(base.score, gamma=gamma))
        out["daily"] = run_config(args, daily, "score", "score-daily", args.seeds, budget, interval)
    return out


def greenhouse(args: LearningArgs) -> dict:
    configs = greenhouse_configs(args)
    trained = {k: v for k, v in configs.items() if args.main or k == "daily"}
    steps = Steps("greenhouse", len(configs) + len(trained))
    refs, runs, errors = {}, {}, {}
    for label, cfg in configs.items():
        t = steps.start(f"references, {_interval_text(compare.action_repeat(cfg))}")
        refs[label] = references(cfg, args.eval_episodes, args.planned_references)
        shown = ", ".join(f"{k} {v['mean']:.1f}" for k, v in refs[label].items())
        steps.done(t, f"references ({label}): {shown}")
    for label, cfg in trained.items():
        res = _train(steps, f"SCORE, {label} decisions", cfg, errors)
        if res is not None:
            runs[label] = summarise_run(res, cfg, refs[label])
    return {
        "env": "greenhouse",
        "seeds": args.seeds,
        "env_steps": greenhouse_budget(args),
        "eval_episodes": args.eval_episodes,
        "action_repeats": {label: compare.action_repeat(cfg) for label, cfg in configs.items()},
        "references": refs,
        "runs": runs,
        "targets": greenhouse_targets(refs, runs, args.seeds),
        "errors": errors,
    }


def _interval_text(repeat: int) -> str:
    return "daily decisions" if repeat == 1 else f"decisions held {repeat} days"


def greenhouse_targets(refs: dict, runs: dict, seeds: int) -> list[dict]:
    """The greenhouse targets (see the module docstring), each met / not met / None."""
    targets = []
    label = next((k for k in refs if k != "daily"), None)  # the main job's decision interval
    main, r8 = runs.get(label), refs.get(label, {})
    expert = r8.get("expert", {}).get("mean")
    if main is not None and expert is not None:
        lowest = min(main["final"]["per_seed"])
        targets.append(
            _target(
                f"every seed's final policy above the expert ({expert:.1f})",
                lowest > expert,
                f"lowest seed {lowest:.1f}",
            )
        )
    constant = r8.get("best constant", {}).get("mean")
    if main is not None:
        iqm = main["final"]["iqm"]["value"]
        name = "IQM of the final policies >= the best constant schedule"
        if constant is None:
            targets.append(_target(name, None, f"IQM {iqm:.1f}; best constant not evaluated"))
        else:
            targets.append(
                _target(f"{name} ({constant:.1f})", iqm >= constant, f"IQM {_fmt(main['final'])}")
            )
        stability = (main.get("stability") or {}).get("per_seed")
        name = "every seed held (no collapse after first beating the default setpoints)"
        if stability:
            held = sum(s["held"] for s in stability.values())
            never = sum(s["first_above"] is None for s in stability.values())
            fell = len(stability) - held - never
            targets.append(
                _target(
                    name,
                    held == len(stability),
                    f"{held} of {len(stability)} held, {fell} fell below the default setpoints "
                    f"after beating them, {never} never beat them",
                )
            )
        else:
            targets.append(_target(name, None, "no training returns logged"))
        wall = main.get("wall_s")
        targets.append(
            _target(
                f"{seeds}-seed run within {WALL_TARGET_S // 60} minutes (measured, not asserted)",
                None if wall is None else wall <= WALL_TARGET_S,
                _seconds(wall),
            )
        )
    daily, r1 = runs.get("daily"), refs.get("daily", {})
    default = r1.get("default", {}).get("mean")
    if daily is not None and default is not None:
        iqm = daily["final"]["iqm"]["value"]
        targets.append(
            _target(
                f"daily decisions: IQM of the final policies above the default setpoints "
                f"({default:.1f})",
                iqm > default,
                f"IQM {_fmt(daily['final'])}",
            )
        )
    return targets


# --- Spider --------------------------------------------------------------------------------


def spider_configs(args: LearningArgs) -> dict[str, TrainConfig]:
    """The Spider runs by algorithm (``score``, ``sac``): ``--spider-seeds`` seeds of
    ``--spider-env-steps`` steps each, the same evaluation schedule."""
    base = dataclasses.replace(args.base, env="spider")
    budget = args.spider_env_steps
    interval = eval_interval(args, base, budget)
    return {
        algo: run_config(args, base, algo, algo, args.spider_seeds, budget, interval)
        for algo in ("score", "sac")
    }


def spider(args: LearningArgs) -> dict:
    configs = spider_configs(args)
    steps = Steps("spider", 1 + len(configs) + int(args.gif))
    runs, errors, results = {}, {}, {}
    t = steps.start("references (standing still, random, open-loop gait)")
    refs = references(configs["score"], args.eval_episodes, False)
    shown = ", ".join(
        f"{k} {v['mean']:.1f} ({v.get('speed', float('nan')):.2f} m/s)" for k, v in refs.items()
    )
    steps.done(t, f"references: {shown}")
    for algo, cfg in configs.items():
        res = _train(steps, LABELS[algo], cfg, errors)
        if res is not None:
            results[algo] = (res, cfg)
            runs[algo] = summarise_run(res, cfg, refs)
    gif = None
    if args.gif:
        t = steps.start("GIF of the best SCORE seed's final policy")
        if "score" in results:
            res, cfg = results["score"]
            gif = render_gif(args, cfg, res)
        steps.done(t, f"GIF: {gif or 'none'}")
    return {
        "env": "spider",
        "seeds": args.spider_seeds,
        "env_steps": args.spider_env_steps,
        "eval_episodes": args.eval_episodes,
        "references": {"spider": refs},
        "runs": runs,
        "targets": spider_targets(refs, runs),
        "gif": gif,
        "gif_steps": args.gif_steps,
        "errors": errors,
    }


def spider_targets(refs: dict, runs: dict) -> list[dict]:
    """The Spider targets (see the module docstring), each met / not met / None."""
    score, sac = runs.get("score"), runs.get("sac")
    targets = []
    if score is None:
        return [_target("SCORE trained", False, "the SCORE run failed")]
    iqm = score["final"]["iqm"]["value"]
    targets.append(
        _target(
            f"SCORE IQM >= {SPIDER_IQM_TARGET:.0f}",
            iqm >= SPIDER_IQM_TARGET,
            f"IQM {_fmt(score['final'])}",
        )
    )
    name = "SCORE above brax SAC (IQMs, and P(SCORE > SAC) > 0.5)"
    if sac is None:
        targets.append(_target(name, None, "the SAC run failed"))
    else:
        p, (lo, hi) = probability_of_improvement(
            score["final"]["per_seed"], sac["final"]["per_seed"], reps=10_000
        )
        sac_iqm = sac["final"]["iqm"]["value"]
        targets.append(
            {
                **_target(
                    name,
                    iqm > sac_iqm and p > 0.5,
                    f"IQM {iqm:.1f} vs {sac_iqm:.1f}; P(SCORE > SAC) "
                    f"{format_interval(p, lo, hi, 2)}",
                ),
                "p_score_better": {"value": p, "lo": lo, "hi": hi},
            }
        )
    gait = refs.get("gait", {}).get("mean")
    if gait is not None:
        targets.append(_target(f"SCORE above the gait ({gait:.1f})", iqm > gait, f"IQM {iqm:.1f}"))
    return targets


def gif_destination(args: LearningArgs) -> str:
    if args.gif_out:
        return args.gif_out
    if os.path.realpath(args.out) == os.path.realpath(COMMITTED_OUT):
        return COMMITTED_GIF
    return os.path.join(args.out, GIF_NAME)


def render_gif(args: LearningArgs, cfg: TrainConfig, res: dict) -> str | None:
    """Render the final policy of the SCORE seed with the best final return to a GIF at
    ``gif_destination`` (kept when it is newer than the run's result); None, with a warning,
    when rendering fails (no OpenGL: ``MUJOCO_GL=osmesa`` and libosmesa6)."""
    dest = gif_destination(args)
    result = os.path.join(cfg.run_dir, "result.json")
    if os.path.exists(dest) and os.path.getmtime(dest) >= os.path.getmtime(result):
        return dest
    k = int(np.argmax(res["returns"]))
    try:
        from score_jax.evaluation.report import render_policy  # deferred: MuJoCo's renderer

        run = restore_run(cfg.run_dir, log=lambda *a: None).for_seed(k)
        with tempfile.TemporaryDirectory() as tmp:
            files = render_policy(run, args.gif_steps, tmp, log=lambda *a: None, png=False)
            os.makedirs(os.path.dirname(os.path.abspath(dest)), exist_ok=True)
            shrink_gif(str(files["gif"][0]), dest)
    except Exception as e:  # rendering is an extra: the numbers stand without it
        print(f"warning: no GIF ({type(e).__name__}: {e}); continuing", flush=True)
        return None
    return dest


def shrink_gif(src: str, dest: str, width: int = GIF_WIDTH, every: int = GIF_EVERY) -> None:
    """``src`` (a GIF of 20 frames per second) as a smaller GIF at ``dest``: every ``every``-th
    frame, ``width`` pixels wide, 64 colours, the same playback speed."""
    from PIL import Image, ImageSequence

    with Image.open(src) as gif:
        duration = gif.info.get("duration", 50)
        frames = [f.convert("RGB") for f in ImageSequence.Iterator(gif)][::every]
    height = round(frames[0].height * width / frames[0].width)
    small = [
        f.resize((width, height), Image.LANCZOS).quantize(64, method=Image.Quantize.MEDIANCUT)
        for f in frames
    ]
    small[0].save(dest, save_all=True, append_images=small[1:], duration=duration * every, loop=0)


# --- outputs -------------------------------------------------------------------------------


def _command(args: LearningArgs) -> str:
    """The command line of this invocation, or for an in-process call the arguments that differ
    from the defaults."""
    argv = sys.argv
    if argv and os.path.basename(argv[0]) == "learning.py":
        return shlex.join(["python", "benchmarks/learning.py", *argv[1:]])
    default = LearningArgs()
    changed = [
        f"{f.name}={getattr(args, f.name)!r}"
        for f in dataclasses.fields(args)
        if f.name != "base" and getattr(args, f.name) != getattr(default, f.name)
    ]
    base = [
        f.name
        for f in dataclasses.fields(args.base)
        if getattr(args.base, f.name) != getattr(default.base, f.name)
    ]
    if base:
        changed.append(f"base=<differs in {', '.join(base)}>")
    return f"benchmarks.learning.main(LearningArgs({', '.join(changed)})) (in-process)"


def _machine(prov: dict) -> str:
    kinds = ", ".join(prov.get("device_kinds", []))
    return (
        f"{platform.machine()}, {os.cpu_count()} CPU cores, {prov.get('platform')}; JAX "
        f"{jax.__version__} on {prov.get('backend')} ({prov.get('device_count')} x {kinds})"
    )


def write(args: LearningArgs, out: dict, seconds: float) -> str:
    """``learning_<env>.{json,md,png}`` in ``--out``; returns their common path stem."""
    prov = provenance()
    git = prov.get("git") or {}
    out = {
        **out,
        "command": _command(args),
        "date_utc": prov["time_utc"],
        "commit": git.get("commit"),
        "dirty": git.get("dirty"),
        "machine": _machine(prov),
        "provenance": prov,
        "wall_s": seconds,
        "args": json.loads(json.dumps(dataclasses.asdict(args), default=str)),
    }
    os.makedirs(args.out, exist_ok=True)
    stem = os.path.join(args.out, f"learning_{out['env']}")
    out["figure"] = os.path.basename(stem) + ".png"
    if out.get("gif"):  # the markdown's link to it, relative to --out
        out["gif_link"] = os.path.relpath(os.path.abspath(out["gif"]), os.path.abspath(args.out))
    plot(out, stem + ".png")
    with open(stem + ".json", "w") as f:
        json.dump(out, f, indent=1)
    with open(stem + ".md", "w") as f:
        f.write(markdown(out))
    return stem


def markdown(out: dict) -> str:
    env = out["env"]
    lines = [f"# Learning targets: {env}", ""]
    if env == "greenhouse":
        lines += [
            f"SCORE with the main job's settings (`TrainConfig()` and `--base`), {out['seeds']} "
            f"seeds in one run, {out['env_steps']} simulated days per seed; final (last) and "
            f"best-evaluated deterministic policies, {out['eval_episodes']} evaluation episodes "
            "each. Returns: season sums of daily cumulative yield (kg m⁻²·day).",
            "",
        ]
    else:
        lines += [
            f"SCORE and brax's SAC, {out['seeds']} seeds each, {out['env_steps']} environment "
            f"steps per seed; final (last) and best-evaluated deterministic policies, "
            f"{out['eval_episodes']} evaluation episodes each; speed: the final policy's x "
            "displacement over simulated time (m/s).",
            "",
        ]
    lines += ["## Targets", "", "| target | value | met |", "|---|---|---|"]
    verdict = {True: "**met**", False: "**not met**", None: "not measured"}
    for t in out["targets"]:
        lines.append(f"| {t['target']} | {t['value']} | {verdict[t['met']]} |")
    lines += ["", "## Per seed", ""]
    for label, run in out["runs"].items():
        lines += _per_seed_table(env, label, run) + [""]
    lines += [
        "## Over seeds (95% stratified-bootstrap intervals)",
        "",
        "| run | policy | IQM | mean | median |",
        "|---|---|---:|---:|---:|",
    ]
    for label, run in out["runs"].items():
        shown = {
            "final": "final return",
            "best": "best return",
            "final_percent_of_open_loop": "final, % of open-loop",
            "speed": "final, speed m/s",
        }
        for which, text in shown.items():
            if run.get(which) is not None:
                s, digits = run[which], 2 if which == "speed" else 1
                lines.append(
                    f"| {_run_name(env, label)} | {text} | {_fmt(s, 'iqm', digits)} | "
                    f"{_fmt(s, 'mean', digits)} | {_fmt(s, 'median', digits)} |"
                )
    lines += ["", "## References", ""]
    intervals = list(out["references"])
    lines += [
        "| policy | "
        + " | ".join(f"{i} decisions" if env == "greenhouse" else "return" for i in intervals)
        + " |",
        "|---|" + "---:|" * len(intervals),
    ]
    names = list(dict.fromkeys(n for i in intervals for n in out["references"][i]))
    for name in names:
        cells = []
        for i in intervals:
            r = out["references"][i].get(name)
            if r is None:
                cells.append("—")
                continue
            cell = f"{r['mean']:.1f}" + (f" ± {r['std']:.1f}" if r["std"] > 1e-6 else "")
            if "speed" in r:
                cell += f" ({r['speed']:.2f} m/s)"
            cells.append(cell)
        lines.append(f"| {_ref_label(env, name)} | " + " | ".join(cells) + " |")
    lines += ["", f"![learning curves]({out['figure']})", ""]
    if out.get("gif"):
        lines += [
            f"The best SCORE seed's final policy ({out['gif_steps']} steps): "
            f"`{_shown_path(out['gif'])}`",
            "",
            f"![SCORE's learned gait]({out['gif_link']})",
            "",
        ]
    if out["errors"]:
        lines += ["## Failed", ""] + [f"- {k}: {e}" for k, e in out["errors"].items()] + [""]
    lines += [
        "## Provenance",
        "",
        f"- Command: `{out['command']}`",
        f"- Commit: `{out['commit']}`" + (" (dirty)" if out["dirty"] else ""),
        f"- Machine: {out['machine']}",
        f"- Date (UTC): {out['date_utc']}",
        f"- Wall time of this invocation: {_seconds(out['wall_s'])}",
    ]
    for label, run in out["runs"].items():
        lines.append(f"- {_run_name(env, label)}: trained in {_seconds(run['wall_s'])}")
    return "\n".join(lines) + "\n"


def _shown_path(path: str) -> str:
    """``path`` relative to the repository when it is inside it."""
    path = os.path.abspath(path)
    return os.path.relpath(path, ROOT) if path.startswith(ROOT + os.sep) else path


def _ref_label(env: str, name: str) -> str:
    labels = SPIDER_REFERENCE_LABELS if env == "spider" else REFERENCE_LABELS
    return labels.get(name, name)


def _run_name(env: str, label: str) -> str:
    if env == "greenhouse":
        return f"SCORE, {label} decisions"
    return LABELS.get(label, label)


def _per_seed_table(env: str, label: str, run: dict) -> list[str]:
    cols = ["final", "best", "best at env step"]
    share = "share_of_open_loop" in run
    if share:
        cols.append("final / open-loop")
    if "speed" in run:
        cols.append("speed m/s")
    stability = (run.get("stability") or {}).get("per_seed")
    if stability:
        cols.append("training (lowest after beating the default)")
    walls = run.get("wall_s_per_seed")
    if walls:
        cols.append("training s")
    lines = [
        f"**{_run_name(env, label)}** ({run['decisions']} decisions x {run['action_repeat']} = "
        f"{run['env_steps']} env steps per seed, {run['num_envs']} envs; trained in "
        f"{_seconds(run['wall_s'])}, "
        + ("seeds one after another)" if walls else "all seeds in one program)"),
        "",
        "| seed | " + " | ".join(cols) + " |",
        "|---|" + "---:|" * len(cols),
    ]
    for k, seed in enumerate(run["seeds"]):
        at = run["best_env_steps"][k] if k < len(run["best_env_steps"]) else None
        cells = [
            f"{run['final']['per_seed'][k]:.1f}",
            "not kept" if run["best"] is None else f"{run['best']['per_seed'][k]:.1f}",
            "—" if at is None else str(at),
        ]
        if share:
            cells.append(f"{100 * run['share_of_open_loop'][k]:.1f}%")
        if "speed" in run:
            cells.append(f"{run['speed']['per_seed'][k]:.2f}")
        if stability:
            s = stability.get(str(seed))
            if s is None or s["first_above"] is None:
                cells.append("never above")
            else:
                word = "held" if s["held"] else "fell below"
                cells.append(f"{s['lowest_after']:.1f} at {s['lowest_at']:.0f} ({word})")
        if walls:
            cells.append(f"{walls[k]:.0f}")
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    return lines


def plot(out: dict, path: str) -> None:
    """Deterministic evaluations against environment steps, one panel per decision interval
    (greenhouse) or one for SCORE and SAC (Spider), references dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env = out["env"]
    if env == "greenhouse":
        # Only the intervals that were trained (--no-main / --no-daily); every interval's
        # references when none was (all runs failed), so the figure still shows them.
        shown = [k for k in out["references"] if k in out["runs"]] or list(out["references"])
        panels = [
            (
                f"SCORE, {_interval_text(out['action_repeats'][label])}",
                {"SCORE": out["runs"][label]} if label in out["runs"] else {},
                out["references"][label],
            )
            for label in shown
        ]
        xlabel = "simulated days (environment steps)"
    else:
        runs = {LABELS[k]: v for k, v in out["runs"].items()}
        panels = [("SCORE vs SAC (brax)", runs, out["references"]["spider"])]
        xlabel = "environment steps"
    fig, axes = plt.subplots(1, len(panels), figsize=(7.5 * len(panels), 4.5), squeeze=False)
    colours = {"SCORE": "tab:green", LABELS["sac"]: "tab:orange"}
    for ax, (title, runs, refs) in zip(axes[0], panels, strict=True):
        for label, run in runs.items():
            curves = {
                c["seed"]: (np.asarray(c["env_steps"], float), np.asarray(c["returns"], float))
                for c in run["curves"]
                if c["env_steps"]
            }
            if curves:
                plot_band(ax, curves, label, colours.get(label, "tab:blue"), "o-")
        greys = plt.cm.Greys(np.linspace(0.35, 0.9, max(1, len(refs))))
        for colour, (name, r) in zip(greys, refs.items(), strict=True):
            ax.axhline(
                r["mean"],
                ls="--",
                lw=1,
                color=colour,
                label=f"{_ref_label(env, name)} ({r['mean']:.1f})",
            )
        ax.set_xlabel(xlabel)
        ax.set_ylabel("episode return (deterministic evaluation)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{env}: learning curves (mean and 95% interval over seeds, seeds faint)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- main ----------------------------------------------------------------------------------


def print_summary(out: dict) -> None:
    verdict = {True: "met", False: "NOT MET", None: "not measured"}
    print(f"\n{out['env']}: targets", flush=True)
    for t in out["targets"]:
        print(f"  [{verdict[t['met']]:>12s}] {t['target']}: {t['value']}", flush=True)
    for label, run in out["runs"].items():
        print(
            f"  {_run_name(out['env'], label)}: final IQM {_fmt(run['final'])}, best IQM "
            f"{_fmt(run['best']) if run['best'] else 'not kept'}",
            flush=True,
        )


def main(args: LearningArgs) -> int:
    """Run the selected parts; 0 when every run trained (targets met or not), 1 otherwise."""
    if "greenhouse" in args.envs and not (args.main or args.daily):
        raise SystemExit("error: --no-main --no-daily leaves no greenhouse run to train")
    compare.refuse_seed_offset(args.base, offset_option="--first-seed S")
    if args.first_seed < 0:
        raise SystemExit(f"error: --first-seed must be >= 0, got {args.first_seed}")
    enable_compile_cache(enabled=args.base.compile_cache)
    args = resolved(args)
    outs = []
    for env in args.envs:
        t0 = time.time()
        out = greenhouse(args) if env == "greenhouse" else spider(args)
        stem = write(args, out, time.time() - t0)
        print_summary(out)
        print(f"wrote {stem}.{{json,md,png}}", flush=True)
        outs.append(out)
    return 1 if any(o["errors"] for o in outs) else 0


if __name__ == "__main__":
    cli_args = tyro.cli(LearningArgs)
    if set(cli_args.envs) == {"greenhouse"}:  # brax (the Spider's SAC) splits devices itself
        from score_jax.run.cpu_split import split_cpu_for_seeds

        split_cpu_for_seeds(resolved(cli_args).seeds, cli_args.base.cpu_devices)
    sys.exit(main(cli_args))
