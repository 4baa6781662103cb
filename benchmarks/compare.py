"""SCORE, its ablations and every baseline on the same env-step budget and seeds (§5, Tables 2/3,
Figs. 6/8).

    python benchmarks/compare.py                 # greenhouse, small budget, 3 seeds
    python benchmarks/compare.py --envs spider --algos score sac isac --seeds 3
    python benchmarks/compare.py --transfer      # + Initial / Converge on unseen sub-spaces
    python benchmarks/compare.py --budget paper  # 1 M env steps per run (the figures' x-axis)
    python benchmarks/compare.py --base.single.hidden 64 64  # any train.py setting for every run

Every row (algorithm or SCORE ablation) trains ``--seeds`` seeds with ``--eval-every`` set, in
ONE run (``--num-seeds``: one compiled program for all seeds; brax's algorithms train their
seeds one after another), then evaluates every seed's final deterministic policy
(``--eval-episodes`` episodes each). Statistics over seeds follow Agarwal et al. 2021
(``score_jax.evaluation.stats``): IQM, mean and median with 95% stratified-bootstrap intervals,
the probability that SCORE improves on each row, and performance profiles. Per environment it
writes to ``--out``:
- ``compare_<env>.json``: per-seed returns, the statistics, learning curves;
- ``compare_<env>.md``: the table (IQM [95% CI] over seeds), Tables 2/3 style;
- ``compare_<env>.png``: learning curves on the full space (Figs. 6a/8a), mean and 95% band;
- ``compare_<env>_profiles.png``: performance profiles of the final returns;
- with ``--transfer``: each row also trains on a subset (``--transfer-subspaces``, default the
  paper's: greenhouse without temperature and irrigation, Spider without two legs), then
  fine-tunes on the full space with transfer.py (columns Initial / Converge); the fixed-width
  baselines get one row per transfer variant (PPO, PPO-mask, PPO-penalty, Table 3);
  ``compare_<env>_transfer.png`` holds the fine-tuning curves (Figs. 6b/8b).

Runs go to ``--work-dir/<env>/<row>/s<first seed>[-<last seed>]``; a run whose ``result.json``
exists is reused, so an interrupted comparison continues where it stopped. Budgets count environment
steps (simulated days on the greenhouse) whatever the action repeat: ``small`` = 160k on the
greenhouse (20k decisions held 8 days), 20k on the Spider, 2k on the probe; ``paper`` = 1 M;
``--env-steps N`` sets it, ``--total-steps N`` gives decisions instead. The wall time of a
comparison is printed per row.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import json
import os
import shutil
import sys
import time
from typing import Literal

import jax
import numpy as np
import tyro

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import envs  # noqa: E402
from score_jax import registry  # noqa: E402
from score_jax.evaluation.curves import mean_and_interval  # noqa: E402
from score_jax.evaluation.stats import (  # noqa: E402
    aggregate,
    format_interval,
    performance_profile,
    plot_performance_profiles,
    probability_of_improvement,
)
from score_jax.evaluation.transfer import TransferArgs, run_transfer  # noqa: E402
from score_jax.run.build import build  # noqa: E402
from score_jax.run.compile_cache import enable_compile_cache  # noqa: E402
from score_jax.run.config import (  # noqa: E402
    TrainConfig,
    critic_owns_encoders,
    from_saved,
    to_dict,
)
from score_jax.run.cpu_split import split_cpu_for_seeds  # noqa: E402
from score_jax.run.driver import train  # noqa: E402
from score_jax.run.side_by_side import run_side_by_side  # noqa: E402

# Environment steps per run (simulated days on the greenhouse), whatever the action repeat: a
# greenhouse decision held 8 days costs 8 of them, so every row sees the same simulated time.
BUDGETS = {
    "small": {"greenhouse": 160_000, "spider": 20_000, "probe": 2_000},
    "paper": {"greenhouse": 1_000_000, "spider": 1_000_000, "probe": 20_000},
}
SUBSETS = {
    "greenhouse": "co2,lighting",
    "spider": "leg_front_left,leg_front_right,leg_back_left,leg_back_right,leg_front,leg_back",
    "probe": "a,b",
}
LABELS = {
    "score": "SCORE",
    "sac": "SAC",
    "ppo": "PPO",
    "hppo": "H-PPO",
    "isac": "ISAC",
    "maddpg": "MADDPG",
    "maac": "MAAC",
    "qmix": "QMIX",
}
# networks sized for the full space: transfer variants plain / mask / penalty (Table 3)
FIXED_WIDTH = ("sac", "ppo", "hppo", "maddpg")
# grown at transfer (their plain row), or built for the full space with mask / penalty (Table 3)
GROWN_WITH_VARIANTS = ("maac", "qmix")
AGG = {"attention": "AL", "mean": "MF", "sum": "SF"}


@dataclasses.dataclass(frozen=True)
class CompareArgs:
    """Train every selected algorithm and SCORE ablation on the same budget and seeds; write
    tables and curves."""

    envs: tuple[Literal["greenhouse", "spider", "probe"], ...] = ("greenhouse",)
    """Environments to compare on."""
    algos: tuple[str, ...] = ()
    """Algorithms (registry names); empty = score and every registered baseline."""
    ablations: Literal["none", "asrl", "single", "full"] = "single"
    """SCORE ablation rows (Table 2): asrl = no ASRL only (AL+HN, the row of Fig. 12); single =
    aggregation mean / sum, no hypernet, no ASRL; full = all 11 combinations."""
    seeds: int = 5
    """Seeds per row (0 .. seeds-1), trained in one run per row (``--num-seeds``)."""
    budget: Literal["small", "paper"] = "small"
    """Environment steps per run (simulated days on the greenhouse): small (160k greenhouse =
    20k decisions held 8 days, 20k Spider) or paper (1 M, the figures' x-axis)."""
    env_steps: int = 0
    """Environment steps per run; overrides --budget when > 0. Each row gets
    ``env_steps // action_repeat`` decisions (its own action repeat)."""
    total_steps: int = 0
    """Decisions per run instead (the old unit; overrides --env-steps and --budget when > 0)."""
    transfer: bool = False
    """Also train on --transfer-subspaces and fine-tune on the full space (Initial / Converge
    columns)."""
    transfer_subspaces: str = ""
    """Subset of the transfer protocol; empty = the paper's for the environment."""
    variants: tuple[Literal["plain", "mask", "penalty"], ...] = ("plain", "mask", "penalty")
    """Transfer variants of the fixed-width baselines (sac, ppo, hppo, maddpg) and, except
    plain (their grown transfer row), of maac and qmix."""
    eval_points: int = 10
    """Deterministic evaluations per run (learning-curve points)."""
    eval_episodes: int = 10
    """Episodes per evaluation."""
    out: str = os.path.join(ROOT, "runs", "benchmarks")
    """Where the tables and plots go (the committed ones: --out benchmarks/results)."""
    work_dir: str = os.path.join(ROOT, "runs", "compare")
    """Where the runs go."""
    base: TrainConfig = TrainConfig(robustness_seeds=0, quiet=True)
    """Settings shared by every run (e.g. --base.score.asrl-steps 500)."""
    jobs: int = 1
    """Rows trained side by side, each in its own process (2 on a 2-core CPU: one row compiles
    while another trains); 1 = one after another in this process."""
    no_train: bool = False
    """Train nothing: tabulate the rows whose result.json is already in --work-dir with these
    settings and list the others as not run (a comparison gathered over several sessions)."""


def rows(args: CompareArgs) -> list[tuple[str, str, dict]]:
    """``(label, algo, TrainConfig overrides)`` of every row; ablations change SCORE's critic."""
    out = [
        (LABELS.get(a, a.upper()), a, {}) for a in (args.algos or tuple(registry.algorithm_names()))
    ]
    if args.ablations != "none" and "score" in [r[1] for r in out]:
        combos = [(asrl, agg, hn) for asrl in (True, False) for agg in AGG for hn in (True, False)]
        if args.ablations == "asrl":
            combos = [(False, "attention", True)]
        elif args.ablations == "single":
            combos = [
                (True, "mean", True),
                (True, "sum", True),
                (True, "attention", False),
                (False, "attention", True),
            ]
        for asrl, agg, hn in combos:
            if (asrl, agg, hn) == (True, "attention", True):
                continue
            label = "+".join((["ASRL"] if asrl else []) + [AGG[agg]] + (["HN"] if hn else []))
            critic = dataclasses.replace(
                args.base.score.critic, aggregation=agg, hypernet=hn, asrl=asrl
            )
            out.append(
                (label, "score", {"score": dataclasses.replace(args.base.score, critic=critic)})
            )
    return out


def _summary(values, seed: int = 0) -> dict:
    """Per-seed values, mean and std, and IQM / mean / median with 95% stratified-bootstrap
    intervals over the seeds (a degenerate interval for one seed)."""
    v = np.asarray(values, float)
    agg = aggregate({"row": v}, reps=10_000, seed=seed)["row"]
    interval = lambda iv: {"value": iv.value, "lo": iv.lo, "hi": iv.hi}
    return {
        "per_seed": v.tolist(),
        "mean": float(v.mean()),
        "std": float(v.std()),
        **{m: interval(agg.metric(m)) for m in ("iqm", "median")},
        "mean_ci": interval(agg.metric("mean")),
    }


def _curves(run_dir: str) -> list[dict]:
    """Each seed's deterministic evaluations ``{"seed", "steps", "returns"}`` from metrics.csv."""
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        rows = [r for r in csv.DictReader(f) if r["eval_return"] not in ("", "nan")]
    seeds = sorted({int(float(r.get("seed", 0))) for r in rows})
    out = []
    for seed in seeds:
        mine = [r for r in rows if int(float(r.get("seed", 0))) == seed]
        out.append(
            {
                "seed": seed,
                "steps": [int(r["env_steps"]) for r in mine],
                "returns": [float(r["eval_return"]) for r in mine],
            }
        )
    return out


def _fresh(run_dir: str) -> None:
    if os.path.exists(run_dir):  # an interrupted run: train it again from scratch
        shutil.rmtree(run_dir)


def _cached(path: str, key: dict) -> dict | None:
    """The result stored at ``path`` if it was produced with the same settings ``key``."""
    if os.path.exists(path):
        saved = json.load(open(path))
        if same_settings(saved.get("key"), key):
            return saved
    return None


def _option_paths(d: dict, prefix: tuple[str, ...] = ()) -> set[tuple[str, ...]]:
    out = set()
    for k, v in d.items():
        out |= _option_paths(v, (*prefix, k)) if isinstance(v, dict) else {(*prefix, k)}
    return out


# A key's non-config fields added since results were stored, at the value those runs had:
# transfer results saved before the encoder switch kept SCORE's critic encoders frozen.
_EXTRAS_BEFORE = {"finetune_critic_encoder": False}


def same_settings(saved_key: dict | None, key: dict) -> bool:
    """Whether a stored result's ``saved_key`` names the run ``key`` asks for. A key written
    before an option existed lacks it: it is read as the run was built, with the option at the
    value it had then (``run.config.from_saved``: the current default, or the old value of a
    changed default), so adding an option does not orphan every stored run. A key naming an
    option that no longer exists matches nothing (what it did cannot be checked)."""
    if saved_key == key:
        return True
    if not isinstance(saved_key, dict) or not isinstance(saved_key.get("config"), dict):
        return False
    config = saved_key["config"]
    if not _option_paths(config) <= _option_paths(key["config"]):
        return False
    extra = {k: v for k, v in saved_key.items() if k != "config"}
    extra |= {k: v for k, v in _EXTRAS_BEFORE.items() if k in key and k not in extra}
    return _key(from_saved(config), **extra) == key


# Where a run lives is not one of its settings: leaving it out of the key lets a work directory
# be moved, copied to another machine or committed (the CPU-scale page's runs) and still be reused.
_PLACE_FIELDS = ("run_dir",)


def _key(cfg: TrainConfig, **extra) -> dict:
    config = {k: v for k, v in to_dict(cfg).items() if k not in _PLACE_FIELDS}
    return json.loads(json.dumps({"config": config, **extra}, default=str))


def _full_cache(cfg: TrainConfig, n_episodes: int, **extra) -> tuple[str, dict]:
    """Where ``run_full`` keeps the result of ``cfg`` and the key it must match."""
    return os.path.join(cfg.run_dir, "result.json"), _key(cfg, episodes=n_episodes, **extra)


def _transfer_cache(cfg: TrainConfig, target: str, steps: int, n_episodes: int):
    """Where ``run_transfer_pair`` keeps its result and the key it must match: the subset run's
    settings and what the fine-tuning trains beyond §4.3's parts (SCORE's critic encoders)."""
    key = _key(
        cfg, episodes=n_episodes, steps=steps, finetune_critic_encoder=critic_owns_encoders(cfg)
    )
    return os.path.join(target, "result.json"), key


def final_returns(run, n_episodes: int) -> list[float]:
    """Each seed's mean return of its final (last) deterministic policy over ``n_episodes``."""
    returns = np.asarray(run.evaluate(run.state.agent, n_episodes).returns)
    return returns.reshape(run.num_seeds, -1).mean(axis=1).tolist()


def run_full(cfg: TrainConfig, n_episodes: int, report=None, log=None) -> dict:
    """Train one run of every seed (or reuse its result.json); each seed's final deterministic
    return and evaluation curve, and ``wall_s``: the wall time of ``train`` (set-up, ASRL and
    compilation included; absent from results cached before it was recorded).

    ``report(run) -> dict``: more numbers of the trained run (e.g. its best policies), stored
    under ``"report"``; its ``__name__`` is part of the cache key. ``log``: where the run's own
    lines go (header, evaluations); default nowhere."""
    extra = {} if report is None else {"report": report.__name__}
    path, key = _full_cache(cfg, n_episodes, **extra)
    cached = _cached(path, key)
    if cached is not None:
        return cached
    _fresh(cfg.run_dir)
    t0 = time.time()
    run = train(cfg, log=log or (lambda *a: None))
    wall = time.time() - t0
    result = {"key": key, "returns": final_returns(run, n_episodes), "curves": _curves(cfg.run_dir)}
    result["wall_s"] = wall
    if report is not None:
        result["report"] = report(run)
    json.dump(result, open(path, "w"))
    return result


def run_transfer_pair(cfg: TrainConfig, target: str, steps: int, n_episodes: int, log=None) -> dict:
    """Train ``cfg`` (a subset run), then fine-tune it on the full space with transfer.py into
    ``target``: the Initial and Converge returns and the fine-tuning curve. ``log``: where both
    runs' own lines go (as in ``run_full``)."""
    path, key = _transfer_cache(cfg, target, steps, n_episodes)
    cached = _cached(path, key)
    if cached is not None:
        return cached
    run_full(cfg, n_episodes, log=log)
    _fresh(target)
    res = run_transfer(
        TransferArgs(
            checkpoint=cfg.run_dir,
            total_steps=steps,
            run_dir=target,
            eval_episodes=n_episodes,
            quiet=True,
        ),
        log=log or (lambda *a: None),
    )
    result = {
        "key": key,
        "initial": res["initial"]["per_seed"],
        "converge": res["converge"]["per_seed"],
        "curves": _curves(target),
    }
    json.dump(result, open(path, "w"))
    return result


@functools.cache
def _grows(cfg: TrainConfig) -> bool:
    run = build(cfg, jax.random.PRNGKey(0), cfg.run_dir, restoring=True, log=lambda *a: None)
    return run.algo.grow is not None


def can_transfer(cfg: TrainConfig) -> bool:
    """Whether transfer.py can take a run of ``cfg``'s algorithm (``Algorithm.grow`` is set);
    checked before training its subset run. One that cannot is listed once, not trained."""
    if _grows(dataclasses.replace(cfg, seed=0, run_dir=None, subspaces=None)):
        return True
    if cfg.seed == 0:
        print(
            f"{cfg.algo}: transfer.py cannot grow its runs (networks tied to fixed sub-spaces); "
            "no transfer rows",
            flush=True,
        )
    return False


def _seeds_dir(seeds: int, first: int = 0) -> str:
    return f"s{first}" if seeds == 1 else f"s{first}-{first + seeds - 1}"


def action_repeat(cfg: TrainConfig) -> int:
    """Environment steps per decision of a run of ``cfg`` (its option, else the env's preset)."""
    if cfg.action_repeat is not None:
        return int(cfg.action_repeat)
    return int(envs.make(cfg.env, **cfg.env_overrides()).hints.action_repeat)


def decisions(args: CompareArgs, env: str) -> tuple[int, int]:
    """``(decisions per run, environment steps per run)`` on ``env`` for ``args``' budget."""
    repeat = action_repeat(dataclasses.replace(args.base, env=env))
    if args.total_steps > 0:
        return args.total_steps, args.total_steps * repeat
    budget = args.env_steps or BUDGETS[args.budget][env]
    if budget < repeat:
        raise ValueError(f"a budget of {budget} env steps is less than one decision ({repeat})")
    return budget // repeat, budget // repeat * repeat


def _transfer_variants(args: CompareArgs, algo: str) -> tuple[str, ...]:
    """The transfer rows of ``algo``: ``plain`` is the grown transfer of an algorithm that grows
    (maac and qmix also take mask / penalty; the fixed-width ones take all three)."""
    if algo in FIXED_WIDTH:
        return args.variants
    if algo in GROWN_WITH_VARIANTS:
        return ("plain",) + tuple(v for v in args.variants if v != "plain")
    return ("plain",)


def refuse_seed_offset(base: TrainConfig, offset_option: str = "") -> None:
    """Rows train seeds 0..K-1 (``row_config``), so a ``--base.seed`` other than 0 is an
    error for every script that builds rows, rather than silently ignored; ``offset_option``
    names the script's own option for a later draw of seeds, if it has one."""
    if base.seed != 0:
        later = f"; a later draw of seeds: {offset_option}" if offset_option else ""
        raise SystemExit(
            f"error: --base.seed {base.seed} is not used here: every run trains seeds 0..K-1 "
            f"(--seeds K){later}"
        )


def row_config(args: CompareArgs, env: str, algo: str, **overrides) -> TrainConfig:
    """The training configuration of one row: ``args.base`` on ``env`` with ``algo``, every
    seed in one run, the budget of ``decisions`` and ``--eval-points`` evaluations."""
    steps, _ = decisions(args, env)
    return dataclasses.replace(
        args.base,
        env=env,
        algo=algo,
        seed=0,
        num_seeds=args.seeds,
        total_steps=steps,
        eval_every=max(1, steps // args.eval_points),
        eval_episodes=args.eval_episodes,
        robustness_seeds=0,
        quiet=True,
        **overrides,
    )


@dataclasses.dataclass(frozen=True)
class Job:
    """One row's training: ``kind`` "full" trains ``cfg``; "transfer" trains the subset run
    ``cfg``, then fine-tunes it for ``steps`` decisions into ``target``."""

    label: str
    kind: Literal["full", "transfer"]
    cfg: TrainConfig
    target: str | None = None
    steps: int = 0

    @property
    def name(self) -> str:
        return f"{self.label} {self.kind}"


def run_job(job: Job, n_episodes: int, log=None) -> dict:
    """``run_full`` or ``run_transfer_pair`` of ``job`` (its result.json reused when present);
    ``log``: where the runs' own lines go (their evaluations), default nowhere."""
    if job.kind == "full":
        return run_full(job.cfg, n_episodes, log=log)
    return run_transfer_pair(job.cfg, job.target, job.steps, n_episodes, log=log)


def run_job_printing(job: Job, n_episodes: int) -> dict:
    """``run_job`` with the runs' own lines printed under ``job.name`` at once: a run of many
    minutes shows its evaluations as they come (side by side, each process prints its own)."""
    return run_job(job, n_episodes, log=lambda m: print(f"    {job.name}: {m}", flush=True))


def cost_order(jobs: list[Job]) -> list[Job]:
    """The jobs, the likely longest first (SCORE's family before the baselines, a transfer pair
    before a single run), so that side by side the last to finish is a short one."""
    score_family = lambda j: j.cfg.algo == "score"
    return sorted(jobs, key=lambda j: (not score_family(j), j.kind != "transfer"))


def env_jobs(args: CompareArgs, env: str) -> list[Job]:
    """Every row's jobs on ``env``: its full-space run and, with ``--transfer``, one subset run
    + fine-tuning per transfer variant."""
    steps, _ = decisions(args, env)
    subset = args.transfer_subspaces or SUBSETS[env]
    jobs = []
    seeds_dir = _seeds_dir(args.seeds)
    for label, algo, overrides in rows(args):
        cfg = row_config(args, env, algo, **overrides)
        slug = label.replace("+", "_").lower()
        run_dir = os.path.join(args.work_dir, env, slug, seeds_dir)
        jobs.append(Job(label, "full", dataclasses.replace(cfg, run_dir=run_dir)))
        if not args.transfer or not can_transfer(cfg):
            continue
        for variant in _transfer_variants(args, algo):
            name = label if variant == "plain" else f"{label}-{variant}"
            as_variant = algo in FIXED_WIDTH or variant != "plain"
            vcfg = dataclasses.replace(
                cfg,
                subspaces=subset,
                single=dataclasses.replace(
                    cfg.single, transfer_variant=variant if as_variant else None
                ),
                run_dir=os.path.join(args.work_dir, env, f"{slug}-{variant}-subset", seeds_dir),
            )
            target = os.path.join(args.work_dir, env, f"{slug}-{variant}-transfer", seeds_dir)
            jobs.append(Job(name, "transfer", vcfg, target, steps))
    return jobs


def run_jobs_side_by_side(jobs: list[Job], n_episodes: int, workers: int, log=print) -> None:
    """Train ``jobs`` (longest first) in ``workers`` processes at once, filling their
    result.json; one that fails there is tried again (and reported) by whoever reads it."""
    pending = [j for j in cost_order(jobs) if not is_done(j, n_episodes)]
    if workers > 1 and len(pending) > 1:
        log(f"training {len(pending)} runs, {workers} side by side:")
        tasks = [(j.name, run_job_printing, (j, n_episodes)) for j in pending]
        run_side_by_side(tasks, workers, log=log)


def is_done(job: Job, n_episodes: int) -> bool:
    """Whether ``job``'s result.json exists with its settings (reading it trains nothing)."""
    if job.kind == "full":
        path, key = _full_cache(job.cfg, n_episodes)
    else:
        path, key = _transfer_cache(job.cfg, job.target, job.steps, n_episodes)
    return _cached(path, key) is not None


def compare_env(args: CompareArgs, env: str) -> dict:
    steps, env_steps = decisions(args, env)
    subset = args.transfer_subspaces or SUBSETS[env]
    jobs = env_jobs(args, env)
    missing = []
    if args.no_train:
        missing = [j.name for j in jobs if not is_done(j, args.eval_episodes)]
        jobs = [j for j in jobs if j.name not in missing]
    else:
        log = lambda m: print(m, flush=True)
        run_jobs_side_by_side(jobs, args.eval_episodes, args.jobs, log=log)
    results, errors, t0 = {}, {}, time.time()
    for i, job in enumerate(jobs):
        label, kind, cfg = job.label, job.kind, job.cfg
        t = time.time()
        print(
            f"[{env} {i + 1}/{len(jobs)}] {label} {kind}, {args.seeds} seeds ...",
            end=" ",
            flush=True,
        )
        try:
            res = run_job(job, args.eval_episodes)
        except Exception as e:  # one failing algorithm must not stop the comparison; it is reported
            errors.setdefault(f"{label} ({kind})", f"{type(e).__name__}: {e}")
            print(f"FAILED ({type(e).__name__}: {str(e)[:200]})", flush=True)
            continue
        results[(label, kind)] = {**res, "run_dir": job.target or cfg.run_dir}
        shown = np.mean(res["returns"] if kind == "full" else res["converge"])
        print(
            f"mean {shown:.2f} ({time.time() - t:.0f} s, {time.time() - t0:.0f} s in all)",
            flush=True,
        )
    return summarise(args, env, steps, subset, results, errors, env_steps, missing)


def summarise(
    args: CompareArgs,
    env: str,
    steps: int,
    subset: str,
    results: dict,
    errors: dict,
    env_steps: int | None = None,
    missing: list[str] | None = None,
) -> dict:
    table = {}
    for (label, kind), res in results.items():
        entry = table.setdefault(label, {})
        where = {"run_dir": res["run_dir"]} if "run_dir" in res else {}
        if kind == "full":
            entry["full"] = {**_summary(res["returns"]), "curves": res["curves"], **where}
        else:
            entry["initial"] = _summary(res["initial"])
            entry["converge"] = {**_summary(res["converge"]), "curves": res["curves"], **where}
    finals = {k: np.asarray(v["full"]["per_seed"]) for k, v in table.items() if "full" in v}
    if "SCORE" in finals:  # P(SCORE > row): the probability that a SCORE seed beats a row's seed
        for label, values in finals.items():
            if label != "SCORE":
                point, (lo, hi) = probability_of_improvement(finals["SCORE"], values, reps=10_000)
                table[label]["full"]["p_score_better"] = {"value": point, "lo": lo, "hi": hi}
    out = {
        "env": env,
        "total_steps": steps,
        "env_steps": env_steps if env_steps is not None else steps,
        "seeds": args.seeds,
        "eval_episodes": args.eval_episodes,
        "transfer_subspaces": subset if args.transfer else None,
        "rows": table,
        "errors": errors,
        "missing": list(missing or []),
    }
    os.makedirs(args.out, exist_ok=True)
    base = os.path.join(args.out, f"compare_{env}")
    json.dump(out, open(base + ".json", "w"), indent=1)
    open(base + ".md", "w").write(markdown(out, args.transfer))
    full_curves = {k: v["full"]["curves"] for k, v in table.items() if "full" in v}
    if full_curves:  # (none with --no-train before any row has run)
        plot(
            full_curves,
            base + ".png",
            f"{env}: full sub-action spaces ({out['env_steps']} env steps = {steps} decisions)",
        )
    if finals:
        lo = min(float(v.min()) for v in finals.values())
        hi = max(float(v.max()) for v in finals.values())
        taus = np.linspace(lo, hi, 50) if hi > lo else np.asarray([lo])
        profiles = performance_profile({k: v for k, v in finals.items()}, taus, reps=2_000)
        plot_performance_profiles(profiles, taus, base + "_profiles.png", xlabel="final return")
    if args.transfer:
        plot(
            {k: v["converge"]["curves"] for k, v in table.items() if "converge" in v},
            base + "_transfer.png",
            f"{env}: fine-tuning on unseen sub-spaces",
        )
    print(markdown(out, args.transfer))
    return out


def markdown(out: dict, transfer: bool) -> str:
    def cell(d):
        if not d:
            return "—"
        iqm = d["iqm"]
        return format_interval(iqm["value"], iqm["lo"], iqm["hi"])

    head = (
        f"Final deterministic evaluation return: IQM [95% stratified-bootstrap CI] over "
        f"{out['seeds']} seeds ({out['eval_episodes']} episodes each), {out['env_steps']} "
        f"environment steps ({out['total_steps']} decisions) per seed on `{out['env']}`; "
        "P(SCORE better): the probability that a SCORE seed beats one of the row's.\n\n"
    )
    cols = ["Fully: Converge", "P(SCORE better)"]
    cols += ["Unseen: Initial", "Unseen: Converge"] if transfer else []
    lines = [
        "| algorithm | " + " | ".join(cols) + " | per-seed (fully) |",
        "|---|" + "---:|" * len(cols) + "---|",
    ]
    for label, v in out["rows"].items():
        full = v.get("full") or {}
        p = full.get("p_score_better")
        cells = [cell(full), "—" if p is None else format_interval(p["value"], p["lo"], p["hi"], 2)]
        if transfer:
            cells += [cell(v.get("initial")), cell(v.get("converge"))]
        seeds = ", ".join(f"{x:.1f}" for x in full.get("per_seed", []))
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {seeds} |")
    errors = "".join(f"\n- {k}: {e}" for k, e in out["errors"].items())
    missing = ", ".join(out.get("missing", []))
    return (
        head
        + "\n".join(lines)
        + ("\n\nFailed:" + errors if errors else "")
        + (f"\n\nNot run yet: {missing}." if missing else "")
        + "\n"
    )


def plot(curves: dict[str, list[dict]], path: str, title: str) -> None:
    """Each row's deterministic evaluations against decisions: the mean over seeds with a 95%
    t-interval (every seed faint)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (label, per_seed) in enumerate(curves.items()):
        data = {
            c["seed"]: (np.asarray(c["steps"], float), np.asarray(c["returns"], float))
            for c in per_seed
            if c["steps"]
        }
        colour = colours[i % len(colours)]
        for steps, values in data.values():
            ax.plot(steps, values, color=colour, alpha=0.2, lw=1)
        summary = mean_and_interval(data)
        if summary is None:
            continue
        grid, mean, lo, hi = summary
        ax.plot(grid, mean, color=colour, lw=2, label=label)
        if lo is not None:
            ax.fill_between(grid, lo, hi, color=colour, alpha=0.2, lw=0)
    ax.set_xlabel("decisions (steps of the action-repeated env)")
    ax.set_ylabel("episode return (deterministic evaluation)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(args: CompareArgs) -> int:
    refuse_seed_offset(args.base)
    # the seeds and rows compile the same programs: compile them once
    enable_compile_cache(enabled=args.base.compile_cache)
    outs = [compare_env(args, env) for env in args.envs]
    for o in outs:
        print(f"wrote {os.path.join(args.out, 'compare_' + o['env'])}.{{json,md,png}}")
    return 1 if any(o["errors"] for o in outs) else 0


if __name__ == "__main__":
    cli_args = tyro.cli(CompareArgs)
    # before JAX starts: one XLA host device per core, so a row's seeds train side by side
    split_cpu_for_seeds(cli_args.seeds, cli_args.base.cpu_devices)
    sys.exit(main(cli_args))
