"""The paper's experiments in one command: Tables 2 and 3, Figures 6 to 12 and a claims table.

    python benchmarks/paper.py --quick                       # a few minutes: the pipeline, small
    python benchmarks/paper.py --seeds 6 --envs greenhouse   # CPU scale (hours)
    python benchmarks/paper.py --out docs                    # regenerate the committed page

For each environment and each setting of the default-centred action prior (``--priors``: on, off
or both; the prior is one switch, ``TrainConfig.default_prior``, for every algorithm), it runs
``benchmarks/compare.py``'s comparison with transfer (every algorithm, the SCORE ablations, the
transfer variants of the fixed-width baselines, all on the same environment-step budget and
seeds, ``--num-seeds`` K seeds in one program per row), each full-space run followed at once
by its robustness sweep, and, on the greenhouse, a SCORE run with the profit reward for Fig. 10.
Every run and sweep is cached in ``--work-dir`` (a run whose ``result.json`` or
``robustness.json`` exists is reused), so a killed invocation continues where it stopped;
compiled programs go to the persistent compilation cache. ``--only NAME ...`` trains a few of
the runs and ``--no-train`` none: the CPU-scale page is gathered over several sessions.

It writes ``<out>/results.md`` and its figures in ``<out>/results/``:

- Figs. 6a/8a (learning curves, Spider / greenhouse) and 6b/8b (fine-tuning on unseen
  sub-spaces), mean and 95% band over seeds;
- Figs. 7/9: every algorithm's robustness, one panel per failure mode;
- Fig. 10 (greenhouse): temperature vs CO2 setpoints at 0/6/12/18 h, yield vs profit reward;
- Fig. 11: the ablations' robustness as a share of their full-space return;
- Fig. 12: t-SNE of the critic's agent embeddings, AL+HN (no ASRL) vs SCORE (needs the
  ``paper`` extra, scikit-learn; without it the page says so);
- Table 2 (SCORE and its ablations, including the eq. 2 ASRL row ``ASRL(eq.2)``: the HVAE
  trained without the action-reconstruction term) and Table 3 (Initial / Converge per
  algorithm and variant), IQM [95% CI] over seeds and the per-seed values;
- the claims of §5 (``score_jax.evaluation.claims``) with a verdict each.

Paper (greenhouse numbering: Fig. 8 = learning and transfer, Fig. 9 = robustness; Spider:
Figs. 6 and 7).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import platform
import shutil
import sys
import time
from collections.abc import Sequence
from typing import Literal

import jax
import numpy as np
import tyro

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from benchmarks import compare  # noqa: E402
from score_jax.evaluation import claims as claims_lib  # noqa: E402
from score_jax.evaluation import paper_figures as figs  # noqa: E402
from score_jax.evaluation.robustness import run_sweep  # noqa: E402
from score_jax.run.build import restore_run  # noqa: E402
from score_jax.run.compile_cache import enable_compile_cache  # noqa: E402
from score_jax.run.config import TrainConfig  # noqa: E402
from score_jax.run.cpu_split import split_cpu_for_seeds  # noqa: E402
from score_jax.run.provenance import git_info  # noqa: E402
from score_jax.run.side_by_side import run_side_by_side  # noqa: E402

FIGURES = {  # (learning, transfer, robustness) figure numbers of the paper per environment
    "spider": ("6a", "6b", "7"),
    "greenhouse": ("8a", "8b", "9"),
    "probe": ("P-a", "P-b", "P-r"),
}
# Environment steps per run (simulated days on the greenhouse). Full: the main job's 144k
# decisions held 8 days on the greenhouse, the learning issue's 500k steps on the Spider.
FULL_BUDGET = {"greenhouse": 1_152_000, "spider": 500_000, "probe": 20_000}
QUICK_BUDGET = {"greenhouse": 16_000, "spider": 4_000, "probe": 1_000}
QUICK_ALGOS = ("score", "isac", "ppo")
QUICK_ASRL_STEPS = 300  # HVAE steps per SCORE run with --quick (ASRL would dominate its runs)
# Decisions between checkpoints with --quick: a few per run instead of about ten (each save
# costs about as much as a hundred decisions of a quick run)
QUICK_CHECKPOINT_EVERY = 1000
EQ2_LABEL = "ASRL(eq.2)"
PROFIT_LABEL = "SCORE (profit)"
FIGURE_DIR = "results"  # next to results.md, which links its figures as results/<file>


@dataclasses.dataclass(frozen=True)
class PaperArgs:
    """Reproduce the paper's tables, figures and claims; write results.md and its figures."""

    quick: bool = False
    """A small version of everything (the greenhouse, SCORE / ISAC / PPO, the no-ASRL ablation,
    2 seeds, 16k simulated days, 300 ASRL steps, the prior on): checks the pipeline in minutes,
    not the claims."""
    seeds: int = 0
    """Seeds per row; 0 = 6 (2 with --quick): at least 5, and a count the cores divide, so that
    a row's seeds train side by side (one XLA device per core)."""
    envs: tuple[Literal["greenhouse", "spider", "probe"], ...] = ()
    """Environments; empty = greenhouse and Spider (greenhouse with --quick)."""
    algos: tuple[str, ...] = ()
    """Algorithms; empty = every registered one (score, isac, ppo with --quick)."""
    ablations: Literal["none", "asrl", "single", "full"] | None = None
    """SCORE ablation rows (compare.py's choices); None = single (asrl with --quick)."""
    eq2_row: bool | None = None
    """Add the Table 2 row with eq. 2's HVAE objective alone (no action-reconstruction term);
    None = yes (no with --quick)."""
    priors: tuple[Literal["on", "off"], ...] = ()
    """Settings of the default-centred action prior to run; empty = both (on with --quick).
    The first one is the headline (figures and claims)."""
    env_steps: int = 0
    """Environment steps per run; 0 = the preset (full: greenhouse 1.152 M = the main job,
    Spider 500k; quick: greenhouse 16k, Spider 4k)."""
    variants: tuple[Literal["plain", "mask", "penalty"], ...] = ("plain", "mask", "penalty")
    """Transfer variants of the fixed-width baselines (Table 3)."""
    eval_points: int = 0
    """Deterministic evaluations per run (curve points); 0 = 8 (2 with --quick)."""
    eval_episodes: int = 0
    """Episodes per evaluation; 0 = 10 (2 with --quick)."""
    robustness_seeds: int = 0
    """Failure draws per robustness setting; 0 = 10 (2 with --quick)."""
    out: str = os.path.join(ROOT, "runs", "benchmarks", "paper")
    """Where results.md and results/ go (the committed page: --out docs)."""
    work_dir: str = os.path.join(ROOT, "runs", "paper")
    """Where the runs go (reused when settings match)."""
    base: TrainConfig = TrainConfig(robustness_seeds=0, quiet=True)
    """Settings shared by every run (e.g. --base.score.asrl-steps 500)."""
    jobs: int = 0
    """Runs and sweeps side by side, each in its own process; 0 = 2 with --quick (a small run
    is mostly compilation, on one core), else 1 (a row's seeds already use every core)."""
    no_train: bool = False
    """Train nothing: write the page from the runs already in --work-dir and list the others as
    not run yet (the CPU-scale page is gathered over several sessions in the committed
    benchmarks/results/paper_runs, kept without checkpoints). A run's robustness sweep and
    figures that read its trained policies are still made where its checkpoints are there."""
    only: tuple[str, ...] = ()
    """Train only these runs (names as in the progress lines: "SCORE full", "ISAC transfer",
    "SCORE (profit) full", ...), each swept after training, then write the page as with
    --no-train: the CPU-scale page's runs, a few per session. Empty = every run."""


@dataclasses.dataclass(frozen=True)
class Plan:
    """``PaperArgs`` with every preset resolved."""

    envs: tuple[str, ...]
    algos: tuple[str, ...]
    ablations: str
    eq2_row: bool
    priors: tuple[str, ...]
    seeds: int
    eval_points: int
    eval_episodes: int
    robustness_seeds: int
    jobs: int


def plan(args: PaperArgs) -> Plan:
    q = args.quick
    return Plan(
        envs=args.envs or (("greenhouse",) if q else ("greenhouse", "spider")),
        algos=args.algos or (QUICK_ALGOS if q else ()),
        ablations=args.ablations or ("asrl" if q else "single"),
        eq2_row=(not q) if args.eq2_row is None else args.eq2_row,
        priors=args.priors or (("on",) if q else ("on", "off")),
        seeds=args.seeds or (2 if q else 6),
        eval_points=args.eval_points or (2 if q else 8),
        eval_episodes=args.eval_episodes or (2 if q else 10),
        robustness_seeds=args.robustness_seeds or (2 if q else 10),
        jobs=args.jobs or (2 if q else 1),
    )


def budget(args: PaperArgs, env: str) -> int:
    return args.env_steps or (QUICK_BUDGET if args.quick else FULL_BUDGET)[env]


def quick_base(args: PaperArgs) -> TrainConfig:
    """``args.base``, with --quick at most ``QUICK_ASRL_STEPS`` ASRL steps per SCORE run and a
    checkpoint every ``QUICK_CHECKPOINT_EVERY`` decisions (unless ``--base`` sets one)."""
    base = args.base
    if not args.quick:
        return base
    if base.checkpoint_every is None:
        base = dataclasses.replace(base, checkpoint_every=QUICK_CHECKPOINT_EVERY)
    if base.score.asrl_steps <= QUICK_ASRL_STEPS:
        return base
    score = dataclasses.replace(base.score, asrl_steps=QUICK_ASRL_STEPS)
    return dataclasses.replace(base, score=score)


def trains_all(args: PaperArgs) -> bool:
    """Whether every missing run is trained (neither --no-train nor --only)."""
    return not args.no_train and not args.only


def with_prior(base: TrainConfig, on: bool) -> TrainConfig:
    """``base`` with the default-centred action prior on or off for every algorithm."""
    return dataclasses.replace(base, default_prior=on)


def compare_args(args: PaperArgs, p: Plan, env: str, prior: str) -> compare.CompareArgs:
    base = with_prior(quick_base(args), prior == "on")
    return compare.CompareArgs(
        envs=(env,),
        algos=p.algos,
        ablations=p.ablations,
        seeds=p.seeds,
        env_steps=budget(args, env),
        transfer=True,
        variants=args.variants,
        eval_points=p.eval_points,
        eval_episodes=p.eval_episodes,
        out=os.path.join(args.work_dir, f"prior-{prior}", "tables"),
        work_dir=os.path.join(args.work_dir, f"prior-{prior}"),
        base=base,
        jobs=p.jobs,
        no_train=not trains_all(args),
    )


def _score_run(cargs: compare.CompareArgs, env: str, name: str, **overrides) -> TrainConfig:
    """A SCORE run of ``cargs``' budget and seeds outside compare.py's rows, in ``name``."""
    run_dir = os.path.join(cargs.work_dir, env, name, compare._seeds_dir(cargs.seeds))
    return compare.row_config(cargs, env, "score", run_dir=run_dir, **overrides)


def eq2_config(cargs: compare.CompareArgs, env: str) -> TrainConfig:
    """Table 2's row with the HVAE trained on eq. 2 alone (action-reconstruction weight 0)."""
    score = cargs.base.score
    hvae = dataclasses.replace(score.hvae, action_recon_weight=0.0)
    return _score_run(cargs, env, "asrl_eq2", score=dataclasses.replace(score, hvae=hvae))


def eq2_row(cargs: compare.CompareArgs, env: str) -> tuple[str, dict]:
    """Table 2's eq. 2 row (``eq2_config``), trained or read back."""
    cfg = eq2_config(cargs, env)
    res = compare.run_full(cfg, cargs.eval_episodes)
    return EQ2_LABEL, {
        "full": {
            **compare._summary(res["returns"]),
            "curves": res["curves"],
            "run_dir": cfg.run_dir,
        }
    }


def profit_config(cargs: compare.CompareArgs, env: str) -> TrainConfig:
    """A SCORE run on the greenhouse with the profit reward (Fig. 10), same budget and seeds."""
    options = tuple(o for o in cargs.base.env_options if not o.startswith("reward="))
    return _score_run(cargs, env, "score_profit", env_options=(*options, "reward='profit'"))


def profit_run(cargs: compare.CompareArgs, env: str) -> str:
    """``profit_config``'s run, trained or read back; its run directory."""
    cfg = profit_config(cargs, env)
    compare.run_full(cfg, cargs.eval_episodes)
    return cfg.run_dir


def _saved_sweep(run_dir: str, n_seeds: int) -> dict | None:
    path = os.path.join(run_dir, "robustness.json")
    if os.path.exists(path):
        saved = json.load(open(path))
        if saved.get("n_seeds") == n_seeds:
            return saved
    return None


def has_policies(run_dir: str) -> bool:
    """Whether ``run_dir`` holds its trained policies (the committed runs keep none)."""
    return os.path.isdir(os.path.join(run_dir, "checkpoints"))


def robustness_of(run_dir: str, n_seeds: int, log=lambda *a: None) -> dict:
    """The run's robustness sweep (``robustness.json``), run once and then read back."""
    saved = _saved_sweep(run_dir, n_seeds)
    if saved is not None:
        return saved
    if not has_policies(run_dir):
        raise FileNotFoundError(f"no robustness.json and no checkpoints in {run_dir}")
    run_sweep(restore_run(run_dir, log=lambda *a: None), n_seeds, log=lambda *a: None)
    log(f"  robustness sweep of {run_dir}")
    return json.load(open(os.path.join(run_dir, "robustness.json")))


def swept(job: compare.Job) -> bool:
    """Whether ``job`` is a full-space run whose robustness sweep the page shows."""
    return job.kind == "full" and job.label != PROFIT_LABEL


def needs_retraining(job: compare.Job, n_seeds: int, n_episodes: int) -> bool:
    """A swept run whose result is there but whose sweep and trained policies are not (a
    committed run, kept without checkpoints, from before its sweep was run)."""
    run_dir = job.cfg.run_dir
    return (
        swept(job)
        and compare.is_done(job, n_episodes)
        and _saved_sweep(run_dir, n_seeds) is None
        and not has_policies(run_dir)
    )


def train_and_sweep(job: compare.Job, n_episodes: int, n_seeds: int) -> None:
    """Train ``job`` (its result.json reused when present), then, for a swept run, its
    robustness sweep at once, while its trained policies are on this machine: the committed
    store keeps no checkpoints, so a sweep left for later could not be run in another session.

    A run that ``needs_retraining`` is trained again first, with the same settings and seeds:
    on the same kind of CPU that gives the same per-seed returns, on another kind (other vector
    instructions, recorded in config.json's provenance) other draws of the same distribution;
    either way its result.json is rewritten by the run its sweep comes from. The runs' own
    lines (their evaluations) are printed under ``job.name`` as they come."""
    if needs_retraining(job, n_seeds, n_episodes):
        os.remove(os.path.join(job.cfg.run_dir, "result.json"))
    compare.run_job_printing(job, n_episodes)
    if swept(job):
        robustness_of(job.cfg.run_dir, n_seeds)


def train_all(jobs: list[compare.Job], p: Plan, log) -> None:
    """Every job not done yet (or that ``needs_retraining``), each followed by its sweep,
    ``p.jobs`` side by side, the likely longest first."""
    n, episodes = p.robustness_seeds, p.eval_episodes
    pending = [
        j
        for j in compare.cost_order(jobs)
        if not compare.is_done(j, episodes) or needs_retraining(j, n, episodes)
    ]
    if not pending:
        return
    log(f"training {len(pending)} runs (each swept after training), {p.jobs} side by side:")
    tasks = [(j.name, train_and_sweep, (j, episodes, n)) for j in pending]
    run_side_by_side(tasks, p.jobs, log=log)


def env_jobs(args: PaperArgs, p: Plan, env: str) -> list[compare.Job]:
    """Every run of ``env`` (each prior's comparison, the eq. 2 row, the profit run), the
    likely longest first."""
    jobs = []
    for prior in p.priors:
        cargs = compare_args(args, p, env, prior)
        jobs += compare.env_jobs(cargs, env)
        if "score" in (p.algos or ("score",)):
            if p.eq2_row:
                jobs.append(compare.Job(EQ2_LABEL, "full", eq2_config(cargs, env)))
            if env == "greenhouse" and prior == p.priors[0]:
                jobs.append(compare.Job(PROFIT_LABEL, "full", profit_config(cargs, env)))
    return compare.cost_order(jobs)


def _full_rows(rows: dict) -> dict:
    return {k: v for k, v in rows.items() if "full" in v and "run_dir" in v["full"]}


def setpoint_figure(run_dirs: dict[str, str], path: str, title: str) -> None:
    """Fig. 10 from SCORE runs by label (seed 0 of each, each with its own reward)."""
    from envs.wrappers import unwrapped

    setpoints = {}
    for label, run_dir in run_dirs.items():
        run = restore_run(run_dir, log=lambda *a: None)
        one = run.for_seed(0)
        setpoints.update(
            figs.season_setpoints(
                unwrapped(run.env),
                {label: run.algo.policy},
                {label: one.state.agent},
                run.agent_index,
                run.spec.action_repeat,
                jax.random.PRNGKey(0),
            )
        )
    figs.plot_setpoints(setpoints, path, title)


def embedding_figure(run_dirs: dict[str, str], path: str, title: str) -> str | None:
    """Fig. 12 from runs by label; None when drawn, else why not (scikit-learn missing)."""
    import importlib.util

    if importlib.util.find_spec("sklearn") is None:
        return "t-SNE needs scikit-learn: pip install -e .[paper]"
    embeddings, names = {}, None
    for label, run_dir in run_dirs.items():
        run = restore_run(run_dir, log=lambda *a: None)
        one = run.for_seed(0)
        embeddings[label] = figs.collect_agent_embeddings(
            run.env, run.algo, one.state.agent, run.agent_index, jax.random.PRNGKey(0)
        )
        names = [run.env.space.names[i] for i in run.agent_index]
    figs.plot_agent_embeddings(embeddings, names, path, title)
    return None


def env_results(args: PaperArgs, p: Plan, env: str, figdir: str, log) -> dict:
    """Every run, sweep and figure of one environment; the data results.md is written from."""
    learn_fig, transfer_fig, robust_fig = FIGURES[env]
    out = {"env": env, "env_steps": budget(args, env), "priors": {}, "figures": {}, "notes": []}
    jobs = env_jobs(args, p, env)
    if args.only:
        jobs = [j for j in jobs if j.name in args.only]
    if not args.no_train:
        train_all(jobs, p, log)
    done = lambda label, kind, cfg: compare.is_done(compare.Job(label, kind, cfg), p.eval_episodes)
    compared = {}
    for prior in p.priors:
        cargs = compare_args(args, p, env, prior)
        log(f"[{env}, prior {prior}] comparison: {len(compare.rows(cargs))} rows x {p.seeds} seeds")
        cmp = compare.compare_env(cargs, env)
        rows = dict(cmp["rows"])
        if p.eq2_row and "score" in (p.algos or ("score",)):
            if not trains_all(args) and not done(EQ2_LABEL, "full", eq2_config(cargs, env)):
                cmp["missing"] = [*cmp.get("missing", []), f"{EQ2_LABEL} full"]
            else:
                label, row = eq2_row(cargs, env)
                rows[label] = row
        compared[prior] = (cmp, rows)
    n = p.robustness_seeds
    dirs = [
        r["full"]["run_dir"] for _, rows in compared.values() for r in _full_rows(rows).values()
    ]
    sweeps = [
        (f"sweep of {d}", robustness_of, (d, n))
        for d in dirs
        if _saved_sweep(d, n) is None and has_policies(d)
    ]
    if p.jobs > 1 and len(sweeps) > 1:
        log(f"{len(sweeps)} robustness sweeps, {p.jobs} side by side:")
        run_side_by_side(sweeps, p.jobs, log=log)
    for prior, (cmp, rows) in compared.items():
        robust = {}
        for label, row in _full_rows(rows).items():
            run_dir = row["full"]["run_dir"]
            if _saved_sweep(run_dir, n) is None and not has_policies(run_dir):
                cmp["missing"] = [*cmp.get("missing", []), f"{label} robustness sweep"]
                continue
            try:
                robust[label] = robustness_of(run_dir, n, log)
            except Exception as e:  # one failed sweep is reported, the page still comes out
                out["notes"].append(f"robustness of {label} (prior {prior}) failed: {e}")
        out["priors"][prior] = {
            "compare": {**cmp, "rows": rows},
            "robustness": robust,
            "claims": claims_lib.check_claims(rows, robust),
        }
    head = out["priors"][p.priors[0]]
    cmp, robust, rows = head["compare"], head["robustness"], head["compare"]["rows"]
    tag = f"{env}, prior {p.priors[0]}"

    def figure(name: str, draw, policies_of: tuple[str, ...] = ()) -> None:
        """Draw Fig. ``name``; one drawn from trained policies (``policies_of``: their run
        directories) is kept from an earlier session while those runs are unchanged and their
        policies are not on this machine (the committed store keeps none)."""
        path = os.path.join(figdir, f"fig{name}_{env}.png")
        if policies_of and not all(has_policies(d) for d in policies_of):
            drawn_at = kept_figure(path, policies_of)
            if drawn_at:
                out["figures"][name] = os.path.basename(path)
                out["notes"].append(
                    f"Fig. {name} is the one drawn {drawn_at} from the same runs (unchanged "
                    "since; their trained policies, which it reads, are not kept in the store)"
                )
                return
        try:
            why = draw(path)
        except Exception as e:  # a figure that cannot be drawn is named on the page
            why = f"{type(e).__name__}: {e}"
        if why:
            out["notes"].append(f"Fig. {name} not drawn: {why}")
        else:
            out["figures"][name] = os.path.basename(path)
            if policies_of:
                record_figure_inputs(path, policies_of)

    src = os.path.join(compare_args(args, p, env, p.priors[0]).out, f"compare_{env}.png")
    figure(learn_fig, lambda path: shutil.copyfile(src, path) and None)
    curves, initial = figs.transfer_curves_from_compare(cmp)
    figure(
        transfer_fig,
        lambda path: figs.plot_transfer_curves(
            curves, path, f"{tag}: fine-tuning on unseen sub-spaces", initial
        ),
    )
    algos = {k: v for k, v in robust.items() if not claims_lib.is_ablation(k) and k != EQ2_LABEL}
    figure(
        robust_fig,
        lambda path: figs.plot_robustness_panels(algos, path, f"{tag}: robustness"),
    )
    ablations = {k: v for k, v in robust.items() if k == "SCORE" or k not in algos}
    if len(ablations) > 1:
        figure(
            "11",
            lambda path: figs.plot_ablation_robustness(
                ablations, path, f"{tag}: ablations' robustness"
            ),
        )
    full = _full_rows(rows)
    if "SCORE" in full and "AL+HN" in full:
        runs = {k: full[k]["full"]["run_dir"] for k in ("AL+HN", "SCORE")}
        figure(
            "12",
            lambda path: embedding_figure(runs, path, f"{tag}: agent embeddings (t-SNE)"),
            tuple(runs.values()),
        )
    if env == "greenhouse" and "SCORE" in full:
        cargs = compare_args(args, p, env, p.priors[0])
        profit = profit_config(cargs, env)
        if not trains_all(args) and not done(PROFIT_LABEL, "full", profit):
            out["notes"].append(
                "Fig. 10 not drawn: the SCORE run with the profit reward is not run yet"
            )
        else:
            runs = {"SCORE, yield reward": full["SCORE"]["full"]["run_dir"]}
            runs["SCORE, profit reward"] = profit_run(cargs, env)
            figure(
                "10",
                lambda path: setpoint_figure(runs, path, f"{tag}: setpoints"),
                tuple(runs.values()),
            )
    return out


def _figure_inputs(run_dirs: Sequence[str]) -> list[dict]:
    """What a figure drawn from trained policies depends on: each run's settings (its result
    key) and final per-seed returns. A retraining that reproduces them (same settings, seeds
    and CPU kind) leaves them unchanged; any other run changes them."""
    inputs = []
    for d in run_dirs:
        saved = json.load(open(os.path.join(d, "result.json")))
        inputs.append({"key": saved["key"], "returns": saved["returns"]})
    return inputs


def _inputs_path(figure_path: str) -> str:
    return os.path.splitext(figure_path)[0] + ".inputs.json"


def record_figure_inputs(figure_path: str, run_dirs: Sequence[str]) -> None:
    """Beside a figure drawn from ``run_dirs``' policies: what it was drawn from, and when."""
    record = {"drawn": time.strftime("%Y-%m-%d"), "runs": _figure_inputs(run_dirs)}
    json.dump(record, open(_inputs_path(figure_path), "w"), indent=1)


def kept_figure(figure_path: str, run_dirs: Sequence[str]) -> str | None:
    """``"on <date>"`` when ``figure_path`` exists and was drawn from ``run_dirs`` as they are
    now (``record_figure_inputs``); else None (not drawn yet, or a run changed since)."""
    record_path = _inputs_path(figure_path)
    if not (os.path.exists(figure_path) and os.path.exists(record_path)):
        return None
    try:
        now = _figure_inputs(run_dirs)
    except (OSError, KeyError, ValueError):
        return None
    record = json.load(open(record_path))
    return f"on {record['drawn']}" if record["runs"] == now else None


def run_origins(results: list[dict]) -> list[str]:
    """``"<commit> (<date>[, dirty]): <n> runs"`` for the runs behind ``results``, from each run's
    config.json (a page gathered over several sessions mixes commits; each is named)."""
    counts: dict[str, int] = {}
    for r in results:
        for res in r["priors"].values():
            for row in res["compare"]["rows"].values():
                for part in ("full", "converge"):
                    run_dir = (row.get(part) or {}).get("run_dir")
                    path = os.path.join(run_dir or "", "config.json")
                    if not run_dir or not os.path.exists(path):
                        continue
                    prov = json.load(open(path)).get("provenance", {})
                    git = prov.get("git") or {}
                    origin = f"`{str(git.get('commit', 'unknown'))[:7]}` ("
                    origin += str(prov.get("time_utc", "unknown date"))[:10]
                    origin += ", dirty)" if git.get("dirty") else ")"
                    counts[origin] = counts.get(origin, 0) + 1
    return [f"{o}: {n} runs" for o, n in sorted(counts.items())]


def _cell(d: dict | None) -> str:
    if not d:
        return "—"
    iqm = d["iqm"]
    return f"{iqm['value']:.1f} [{iqm['lo']:.1f}, {iqm['hi']:.1f}]"


def _seeds(d: dict | None) -> str:
    return ", ".join(f"{x:.1f}" for x in (d or {}).get("per_seed", [])) or "—"


def tables_markdown(rows: dict) -> str:
    """Table 2 (SCORE and its ablations) and Table 3 (transfer: Initial / Converge)."""
    t2 = [
        "| SCORE variant | full space: final return | unseen: Converge | per seed (full) |",
        "|---|---:|---:|---|",
    ]
    for label, v in rows.items():
        if label == "SCORE" or claims_lib.is_ablation(label) or label == EQ2_LABEL:
            shown = "ASRL+AL+HN (SCORE)" if label == "SCORE" else label
            t2.append(
                f"| {shown} | {_cell(v.get('full'))} | {_cell(v.get('converge'))} "
                f"| {_seeds(v.get('full'))} |"
            )
    t3 = [
        "| algorithm (variant) | full space | unseen: Initial | unseen: Converge "
        "| per seed (Converge) |",
        "|---|---:|---:|---:|---|",
    ]
    for label, v in rows.items():
        if not claims_lib.is_ablation(label) and label != EQ2_LABEL:
            t3.append(
                f"| {label} | {_cell(v.get('full'))} | {_cell(v.get('initial'))} "
                f"| {_cell(v.get('converge'))} | {_seeds(v.get('converge'))} |"
            )
    return (
        "Table 2 (ablations):\n\n"
        + "\n".join(t2)
        + "\n\nTable 3 (transfer to unseen sub-spaces):\n\n"
        + "\n".join(t3)
    )


def page(
    args: PaperArgs, p: Plan, results: list[dict], seconds: float, git: dict | None = None
) -> str:
    """results.md. ``git``: the checkout's ``git_info()`` taken before anything was written (a
    page written into the repository, ``--out docs``, would otherwise call its own figures a
    dirty tree); None = now."""
    git = (git_info() if git is None else git) or {}
    cmd = "python benchmarks/paper.py " + " ".join(sys.argv[1:])
    lines = [
        "# The paper's experiments, reproduced",
        "",
        "Generated by `benchmarks/paper.py`; do not edit by hand.",
        "",
        f"- Command: `{cmd.strip()}`",
        f"- Commit: `{git.get('commit', 'unknown')}`" + (" (dirty)" if git.get("dirty") else ""),
        f"- Machine: {platform.machine()}, {os.cpu_count()} CPU cores, JAX {jax.__version__} on "
        f"{jax.devices()[0].platform}; {seconds / 60:.1f} min for this invocation "
        "(cached runs not counted again)",
        f"- Date: {datetime.date.today().isoformat()}",
        "- Runs trained at: " + ("; ".join(run_origins(results)) or "none"),
        f"- Settings: {p.seeds} seeds per row, {p.eval_episodes} evaluation episodes, "
        f"{p.robustness_seeds} failure draws per robustness setting, prior "
        + " and ".join(p.priors)
        + (" (quick: checks the pipeline, not the claims)" if args.quick else ""),
        "",
        "Every number is an IQM with its 95% stratified-bootstrap interval over seeds; verdicts "
        "compare per-seed values by the probability of improvement (see "
        "`score_jax/evaluation/claims.py`).",
    ]
    if args.quick:
        lines += [
            "",
            "**This is the `--quick` check of the pipeline** (few seeds, a small fraction of the "
            "main job's budget, 300 ASRL steps): its numbers and verdicts say nothing about the "
            "paper's claims. The page at CPU scale is `python benchmarks/paper.py --out docs` "
            "(6 seeds per row at the main job's budget: many hours on 2 cores per environment).",
        ]
    for r in results:
        env = r["env"]
        for prior, res in r["priors"].items():
            cmp = res["compare"]
            lines += [
                "",
                f"## {env}, default-centred prior {prior}",
                "",
                f"{cmp['env_steps']} environment steps ({cmp['total_steps']} decisions) per "
                f"run, {cmp['seeds']} seeds per row; transfer sub-spaces "
                f"`{cmp['transfer_subspaces']}`.",
                "",
                "### Claims",
                "",
                claims_lib.claims_markdown(res["claims"]),
            ]
            if cmp.get("missing"):
                lines += [
                    "",
                    f"**Partial:** {len(cmp['missing'])} runs or sweeps of this setting are not "
                    "run yet, so these verdicts compare only the rows below and may change. Not "
                    "run yet: " + ", ".join(cmp["missing"]) + ".",
                ]
            lines += [
                "",
                "### Tables",
                "",
                tables_markdown(cmp["rows"]),
            ]
            if cmp.get("errors"):
                lines += [
                    "",
                    "Failed rows: " + "; ".join(f"{k}: {v}" for k, v in cmp["errors"].items()),
                ]
        lines += ["", f"### Figures ({env}, prior {next(iter(r['priors']))})", ""]
        for name, file in r["figures"].items():
            lines.append(f"Fig. {name}:\n\n![Fig. {name}](results/{file})\n")
        lines += [f"- {n}" for n in r["notes"]]
    return "\n".join(lines) + "\n"


def check_only(args: PaperArgs, p: Plan) -> None:
    """An --only name that is not one of the plan's runs is an error that lists them."""
    if not args.only:
        return
    names = {j.name for env in p.envs for j in env_jobs(args, p, env)}
    unknown = [n for n in args.only if n not in names]
    if unknown:
        raise SystemExit(
            f"error: --only {', '.join(map(repr, unknown))}: not a run of this plan; "
            f"the runs are: {', '.join(sorted(names))}"
        )


def main(args: PaperArgs) -> int:
    compare.refuse_seed_offset(args.base)
    enable_compile_cache()
    p = plan(args)
    check_only(args, p)
    figdir = os.path.join(args.out, FIGURE_DIR)
    os.makedirs(figdir, exist_ok=True)
    t0 = time.time()
    git = git_info()  # before the figures land in a tracked --out (docs/)
    log = lambda m: print(m, flush=True)
    results = [env_results(args, p, env, figdir, log) for env in p.envs]
    text = page(args, p, results, time.time() - t0, git)
    with open(os.path.join(args.out, "results.md"), "w") as f:
        f.write(text)
    with open(os.path.join(figdir, "results.json"), "w") as f:
        json.dump(results, f, indent=1, default=lambda o: np.asarray(o).tolist())
    log(text)
    log(f"wrote {os.path.join(args.out, 'results.md')} ({(time.time() - t0) / 60:.1f} min)")
    failed = any(res["compare"].get("errors") for r in results for res in r["priors"].values())
    return 1 if failed else 0


if __name__ == "__main__":
    cli_args = tyro.cli(PaperArgs)
    # before JAX starts: one XLA host device per core, so a row's seeds train side by side
    split_cpu_for_seeds(plan(cli_args).seeds, cli_args.base.cpu_devices)
    sys.exit(main(cli_args))
