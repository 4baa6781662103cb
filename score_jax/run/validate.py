"""Everything about a command's configuration that can be checked before any computation.

Every command checks its whole configuration first and reports every problem at once, one
message each, as a ``UsageError`` (the command line prints ``error: <problem>`` lines and exits
with 2), before it builds a network, runs ASRL or writes a file:

- ``validate_train_config(cfg)``: budgets, replay and batch sizes, schedules and every
  number of every section (finite, in range), known environment and algorithm names, the
  environment's options typed against its config fields (``envs.parse_options``) and the
  environment built from them (a missing weather file is a problem here), sub-space names, the
  device split of a data-parallel run (``--distributed``: whole seeds on every device of every
  process), and the run directory (one that already holds a run is
  refused unless resumed);
- ``prepare_train(cfg)``: what ``run.driver.train`` calls first. A ``--resume DIR`` takes the
  run's saved configuration (``config.json``, else the newest readable checkpoint); an option
  given on the command line that differs from both its default and the saved value is a
  conflict, except ``--total-steps N``, which extends the run to ``N`` decisions (more than its
  checkpoint holds), and the options of the end-of-run report;
- ``validate_transfer_args`` and ``validate_robustness_args``: the same for ``score-transfer``
  and ``score-robustness``; neither creates anything on a path it only reads.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator
from typing import Any

import jax

import envs
from score_jax import registry
from score_jax.run.checkpoint import Checkpointer, CheckpointError, saved_run_config
from score_jax.run.config import (
    TrainConfig,
    TransferSpec,
    critic_owns_encoders,
    default_run_dir,
    from_saved,
)
from score_jax.run.external import RESUME_ERROR

MAX_SEED = 2**31 - 1 - 100_000  # the run derives further seeds by adding up to 50_000

# Integer options that may be 0 (every other integer, and every entry of a tuple of widths,
# must be >= 1; None, where allowed, means "the preset").
ZERO_OK = frozenset(
    {"eval_every", "robustness_seeds", "learning_starts", "train_failures"}
    | {"train_failure_mode", "asrl_steps", "min_replay_size", "process_id"}
)
UNIT_INTERVAL = frozenset(
    {"gamma", "discounting", "gae_lambda", "dropnode_prob", "qmix_eps_start", "qmix_eps_end"}
    | {"critic_pessimism"}
)
POSITIVE = frozenset(
    {"actor_lr", "critic_lr", "alpha_lr", "learning_rate", "init_alpha", "grad_clip"}
    | {"max_grad_norm", "action_recon_std", "gumbel_temperature", "clipping_epsilon", "tau"}
    | {"reward_scale", "reward_scaling", "code_contrast_temperature"}
)
NON_NEGATIVE = frozenset(
    {
        "entropy_cost",
        "penalty_coef",
        "kl_weight",
        "action_recon_weight",
        "maddpg_noise",
        "exploration_shift",
    }
    | {"discrete_entropy_scale", "head_init_scale", "code_contrast_weight"}
)
# Options of the end-of-run report: a resumed run may change them.
REPORT_OPTIONS = frozenset(
    {"quiet", "render", "render_steps", "robustness_seeds", "planned_references"}
)
# How the processes of a run are launched: a resumed run takes them from the command line only.
LAUNCH_OPTIONS = frozenset({"distributed", "coordinator_address", "num_processes", "process_id"})


class UsageError(ValueError):
    """A command's configuration has problems (``problems``: one message each)."""

    def __init__(self, problems):
        self.problems = [" ".join(str(p).split()) for p in problems]
        super().__init__("; ".join(self.problems))


def flag(path: str) -> str:
    """The command-line spelling of a dotted field path (``off_policy.num_envs`` ->
    ``--off-policy.num-envs``)."""
    return "--" + path.replace("_", "-")


def _leaves(obj, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``(dotted path, value)`` of every non-dataclass field of a (nested) dataclass."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            yield from _leaves(value, f"{prefix}{f.name}.")
        else:
            yield prefix + f.name, value


def _sections(obj, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``(dotted prefix, dataclass)`` of ``obj`` and every nested dataclass."""
    yield prefix, obj
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            yield from _sections(value, f"{prefix}{f.name}.")


def _number_problems(cfg: TrainConfig) -> list[str]:
    """Every number of every section: finite, and in the range its name implies."""
    out = []
    for path, value in _leaves(cfg):
        name = path.rsplit(".", 1)[-1]
        if value is None or isinstance(value, (bool, str)):
            continue
        if isinstance(value, float):
            if not math.isfinite(value):
                out.append(f"{flag(path)} {value}: must be a finite number")
            elif name in UNIT_INTERVAL and not 0.0 <= value <= 1.0:
                out.append(f"{flag(path)} {value}: must be in [0, 1]")
            elif name in POSITIVE and not value > 0.0:
                out.append(f"{flag(path)} {value}: must be > 0")
            elif name == "tau" and value > 1.0:
                out.append(f"{flag(path)} {value}: must be in (0, 1]")
            elif name in NON_NEGATIVE and value < 0.0:
                out.append(f"{flag(path)} {value}: must be >= 0")
        elif isinstance(value, int) and name != "seed":
            low = 0 if name in ZERO_OK else 1
            if value < low:
                out.append(f"{flag(path)} {value}: must be >= {low}")
        elif isinstance(value, tuple) and all(isinstance(v, int) for v in value):
            if any(v < 1 for v in value):
                shown = " ".join(map(str, value))
                out.append(f"{flag(path)} {shown}: every width must be >= 1")
    if not 0 <= cfg.seed <= MAX_SEED:
        out.append(f"--seed {cfg.seed}: must be in 0..{MAX_SEED}")
    if cfg.off_policy.train_failure_mode not in (0, 1, 2):
        out.append(
            f"--off-policy.train-failure-mode {cfg.off_policy.train_failure_mode}: must be "
            "0 (default), 1 (random) or 2 (last)"
        )
    for prefix, section in _sections(cfg):
        lo, hi = getattr(section, "log_std_min", None), getattr(section, "log_std_max", None)
        if isinstance(lo, float) and isinstance(hi, float) and not lo < hi:
            out.append(
                f"{flag(prefix + 'log_std_min')} {lo} must be below "
                f"{flag(prefix + 'log_std_max')} {hi}"
            )
    return out


def committed_steps(run_dir: str) -> list[int]:
    """The committed checkpoint steps of the run in ``run_dir`` (oldest first; empty when there
    are none). Creates nothing."""
    try:
        ckpt = Checkpointer(run_dir, create=False)
    except CheckpointError:
        return []
    try:
        return ckpt.all_steps()
    finally:
        ckpt.close()


def _run_dir_problems(run_dir: str, option: str) -> list[str]:
    """A directory a new run will write into: not a file, writable, not holding a run."""
    if os.path.exists(run_dir) and not os.path.isdir(run_dir):
        return [f"{option} {run_dir}: exists and is not a directory"]
    steps = committed_steps(run_dir)
    if steps:
        return [
            f"{option} {run_dir} already holds a run (checkpoint at step {steps[-1]}); pass "
            f"--resume {run_dir} to continue it or choose another {option}"
        ]
    parent = os.path.abspath(run_dir)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.access(parent, os.W_OK):
        return [f"{option} {run_dir}: {parent} is not writable"]
    return []


def _subspace_names(text: str | None, option: str = "--subspaces") -> tuple[list, list[str]]:
    """``(names, problems)`` of a comma-separated sub-space list (None: all sub-spaces)."""
    if text is None:
        return [], []
    names = [x.strip() for x in text.split(",")]
    problems = []
    if any(not n for n in names):
        problems.append(f"{option} {text!r}: empty sub-space name (write names like a,b)")
    names = [n for n in names if n]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        problems.append(f"{option} {text!r}: {', '.join(twice)} given more than once")
    return names, problems


def _unknown_subspaces(names, space, option: str = "--subspaces") -> list[str]:
    unknown = [n for n in names if n not in space.names]
    if not unknown:
        return []
    return [
        f"{option}: unknown sub-space(s) {', '.join(unknown)}; this environment has "
        f"{', '.join(space.names)}"
    ]


def _make_env(cfg: TrainConfig) -> tuple[Any, list[str]]:
    """The raw environment of ``cfg`` (None and the problems when its options are bad)."""
    try:
        overrides, problems = envs.parse_options(cfg.env, cfg.env_options)
        if problems:
            return None, [f"--env-options: {p}" for p in problems]
        return envs.make(cfg.env, **overrides), []
    except OSError as e:
        where = f": {e.filename}" if e.filename else ""
        return None, [f"--env-options: {e.strerror or e}{where}"]
    except Exception as e:  # building from the user's options is the check itself
        return None, [f"--env-options: {cfg.env} cannot be built ({type(e).__name__}: {e})"]


def _check_train(cfg: TrainConfig, resuming: bool = False) -> tuple[list[str], Any]:
    """``(problems, raw environment or None)`` of ``cfg``."""
    problems = []
    env_names, algo_names = envs.registered_names(), registry.algorithm_names()
    if cfg.env not in env_names:
        problems.append(f"--env {cfg.env}: unknown environment; known: {', '.join(env_names)}")
    if cfg.algo not in algo_names:
        problems.append(f"--algo {cfg.algo}: unknown algorithm; known: {', '.join(algo_names)}")
    problems += _number_problems(cfg)
    names, name_problems = _subspace_names(cfg.subspaces)
    problems += name_problems
    o = cfg.off_policy
    in_process = cfg.algo not in algo_names or registry.entry(cfg.algo).in_process
    if in_process and o.batch_size > o.replay_capacity >= 1:
        problems.append(
            f"--off-policy.batch-size {o.batch_size} is larger than --off-policy.replay-capacity "
            f"{o.replay_capacity}: the buffer could never hold a batch"
        )
    devices = jax.device_count()
    problems += _distributed_problems(cfg, in_process, devices)
    # seeds that divide evenly over the devices are sharded whole (SeedTrainer); otherwise each
    # seed's environments and batches are
    by_envs = in_process and cfg.data_parallel and devices > 1 and cfg.num_seeds % devices
    if by_envs and not cfg.distributed:  # (distributed: whole seeds per device, checked above)
        for name in ("num_envs", "batch_size"):
            n = getattr(o, name)
            if n >= 1 and n % devices:
                problems.append(
                    f"{flag('off_policy.' + name)} {n} must be a multiple of the {devices} "
                    "devices of the data-parallel run (or pass --no-data-parallel)"
                )
    elif (
        not in_process
        and not cfg.distributed
        and cfg.single.num_envs >= 1
        and cfg.single.num_envs % devices
    ):
        problems.append(  # brax's loops always use every device
            f"--single.num-envs {cfg.single.num_envs} must be a multiple of the {devices} "
            "devices brax trains on"
        )
    variant = cfg.single.transfer_variant
    if variant is not None and cfg.algo in algo_names and not registry.entry(cfg.algo).variants:
        takes = ", ".join(n for n in algo_names if registry.entry(n).variants)
        problems.append(
            f"--single.transfer-variant {variant}: {cfg.algo} has no transfer variants (they "
            f"are for the baselines built for the full space: {takes})"
        )
    if resuming and not in_process:
        problems.append(RESUME_ERROR.format(algo=cfg.algo, run_dir=cfg.resume))
    if not resuming:
        problems += _run_dir_problems(default_run_dir(cfg), "--run-dir")
    if cfg.env not in env_names:
        return problems, None
    raw, env_problems = _make_env(cfg)
    problems += env_problems
    if raw is None:
        return problems, None
    problems += _unknown_subspaces(names, raw.space)
    problems += _env_problems(cfg, raw, names, in_process)
    return problems, raw


def _distributed_problems(cfg: TrainConfig, in_process: bool, devices: int) -> list[str]:
    """``--distributed``: JAX joined to the other processes, an in-process algorithm, and whole
    seeds on every device of every process."""
    if not cfg.distributed:
        given = [n for n in sorted(LAUNCH_OPTIONS - {"distributed"}) if getattr(cfg, n) is not None]
        return [f"{flag(n)} needs --distributed" for n in given]
    if not jax.distributed.is_initialized():
        return [
            "--distributed: jax.distributed is not initialized (score-train does it before JAX "
            "starts; a program calling run.driver.train must call "
            "score_jax.run.distributed.initialize(cfg) first)"
        ]
    if not in_process:
        return [
            f"--distributed trains in-process algorithms only; {cfg.algo} trains inside brax's "
            "own loop, which runs on one process"
        ]
    if not cfg.data_parallel:
        return [
            "--distributed shards the seeds over every process's devices: drop --no-data-parallel"
        ]
    if cfg.num_seeds % devices:
        procs = jax.process_count()
        return [
            f"--num-seeds {cfg.num_seeds} must be a multiple of the {devices} devices of the "
            f"{procs} process{'es' if procs != 1 else ''} (--distributed trains whole seeds on "
            "every device of every process)"
        ]
    return []


def _env_problems(cfg: TrainConfig, raw, names, in_process: bool) -> list[str]:
    """The checks that need the environment (its space and presets)."""
    out = []
    space, hints = raw.space, raw.hints
    if cfg.action_width is not None and 1 <= cfg.action_width < space.max_dim:
        out.append(
            f"--action-width {cfg.action_width} is below the environment's widest sub-space "
            f"({space.max_dim})"
        )
    if cfg.render and not hasattr(raw, "mj_model"):
        out.append(f"--render needs a MuJoCo environment (spider); {cfg.env} has no body to draw")
    n_agents = len([n for n in names if n in space.names]) or space.n
    o = cfg.off_policy
    if o.train_failures >= n_agents >= 1 and o.train_failures >= 1:
        out.append(
            f"--off-policy.train-failures {o.train_failures} must be below the {n_agents} "
            "controlled sub-spaces (at least one has to act)"
        )
    total = hints.total_steps if cfg.total_steps is None else cfg.total_steps
    if total < 1:
        return out
    if in_process and min(o.num_envs, o.steps_per_epoch, o.batch_size) >= 1:
        spe = o.num_envs * o.steps_per_epoch
        run_steps = -(-total // spe) * spe
        first = max(o.learning_starts, o.batch_size)
        if run_steps < first:
            out.append(
                f"the run ends after {run_steps} decisions (--total-steps {total}, in epochs of "
                f"{spe}), before its first gradient update (--off-policy.learning-starts "
                f"{o.learning_starts}, --off-policy.batch-size {o.batch_size}): it would not learn"
            )
    elif cfg.algo in ("ppo", "hppo"):
        p, n = cfg.single.ppo, cfg.single.num_envs
        if n >= 1 and p.batch_size >= 1 and (p.batch_size * p.num_minibatches) % n:
            out.append(
                f"--single.ppo.batch-size {p.batch_size} x --single.ppo.num-minibatches "
                f"{p.num_minibatches} must be a multiple of --single.num-envs {n}"
            )
    elif cfg.algo == "sac" and cfg.single.sac.min_replay_size >= total:
        out.append(
            f"--single.sac.min-replay-size {cfg.single.sac.min_replay_size} must be below the "
            f"run's {total} env steps"
        )
    return out


def validate_train_config(cfg: TrainConfig, resuming: bool = False) -> list[str]:
    """Every problem of ``cfg`` (one message each; empty when it is fine), found without building
    networks or running anything. ``resuming``: the run continues in its own directory (which
    must then hold it) instead of starting in an empty one."""
    return _check_train(cfg, resuming)[0]


def _changed_options(cli: TrainConfig, saved: TrainConfig) -> list[tuple[str, Any, Any]]:
    """``(path, given, saved)`` of the options given on the command line (different from the
    default) that differ from the saved configuration."""
    default = dict(_leaves(TrainConfig()))
    saved_values = dict(_leaves(saved))
    return [
        (path, value, saved_values.get(path))
        for path, value in _leaves(cli)
        if value != default[path] and value != saved_values.get(path)
    ]


def _show(value) -> str:
    return " ".join(map(str, value)) if isinstance(value, tuple) else str(value)


def resume_config(
    cli: TrainConfig, log=print
) -> tuple[TrainConfig | None, TransferSpec | None, dict | None, list[str]]:
    """``--resume DIR`` resolved against the run saved in DIR.

    Returns ``(config, transfer, record, problems)``: the configuration to continue with (the
    saved one, in DIR, with the command line's report options and an extended budget; its
    ``resume`` is None when DIR holds no checkpoint yet, so the run starts over with its saved
    configuration), the run's transfer spec, what to add to its ``config.json`` (None: leave
    it), and every problem.
    """
    run_dir = cli.resume
    if not os.path.isdir(run_dir):
        return None, None, None, [f"--resume {run_dir}: no such directory"]
    try:
        saved_dict, transfer_dict = saved_run_config(run_dir)
    except CheckpointError as e:
        return None, None, None, [f"--resume {run_dir}: {e}"]
    saved = from_saved(saved_dict)
    steps = committed_steps(run_dir)
    done = steps[-1] if steps else 0
    problems, record = [], None
    for path, given, was in _changed_options(cli, saved):
        if path in REPORT_OPTIONS | LAUNCH_OPTIONS or path in ("resume", "total_steps"):
            continue
        if path == "run_dir" and os.path.abspath(given) == os.path.abspath(run_dir):
            continue
        problems.append(
            f"{flag(path)} {_show(given)} conflicts with the resumed run's {_show(was)} (a resumed "
            "run keeps its saved configuration; only --total-steps can extend it)"
        )
    resolved_total = (saved_dict.get("resolved") or {}).get("total_steps", saved.total_steps)
    total = saved.total_steps
    if cli.total_steps is not None and cli.total_steps not in (saved.total_steps, resolved_total):
        if cli.total_steps <= done:
            problems.append(
                f"--total-steps {cli.total_steps}: the run has already done {done} decisions "
                f"(its checkpoint); pass more than {done} to extend it"
            )
        else:
            total = cli.total_steps
            extensions = list(saved_dict.get("extensions") or [])
            extensions.append(
                {"at_step": done, "from_total_steps": resolved_total, "to_total_steps": total}
            )
            record = {"extensions": extensions}
    given = lambda name: getattr(cli, name) != getattr(TrainConfig, name)  # the CLI's own
    report = {n: getattr(cli if given(n) else saved, n) for n in REPORT_OPTIONS}
    report.update({n: getattr(cli, n) for n in LAUNCH_OPTIONS})
    cfg = dataclasses.replace(saved, resume=run_dir, run_dir=run_dir, total_steps=total, **report)
    transfer = None if transfer_dict is None else TransferSpec.from_dict(transfer_dict)
    if not steps and not problems:
        if transfer is not None:
            problems.append(
                f"--resume {run_dir}: this transfer run has no checkpoint yet; run score-transfer "
                "again to start it"
            )
        else:
            log(f"{run_dir} holds no checkpoint yet: starting it over with its saved configuration")
            cfg = dataclasses.replace(cfg, resume=None)
    return cfg, transfer, record, problems


def prepare_train(
    cfg: TrainConfig, transfer: TransferSpec | None = None, log=print
) -> tuple[TrainConfig, TransferSpec | None, dict | None]:
    """The first step of ``run.driver.train``: ``cfg`` resolved (a ``--resume`` against its saved
    run, see ``resume_config``) and validated. Returns ``(config, transfer, record)``, where
    ``record`` is what to add to the run's ``config.json`` (None: write it only for a new
    run). Raises ``UsageError`` with every problem."""
    record = None
    if cfg.resume:
        resumed, saved_transfer, record, problems = resume_config(cfg, log)
        if resumed is None:
            raise UsageError(problems)
        cfg, transfer = resumed, saved_transfer
        problems += validate_train_config(cfg, resuming=bool(cfg.resume))
    else:
        problems = validate_train_config(cfg)
    if problems:
        raise UsageError(problems)
    return cfg, transfer, record


def _source_run(option: str, run_dir: str) -> tuple[TrainConfig | None, list[str]]:
    """The saved configuration of the finished run a command reads (nothing is created)."""
    if not os.path.isdir(run_dir):
        return None, [f"{option} {run_dir}: no such directory"]
    if not committed_steps(run_dir):
        return None, [f"{option} {run_dir}: no run there (no checkpoint in {run_dir}/checkpoints)"]
    try:
        saved, _ = saved_run_config(run_dir)
    except CheckpointError as e:
        return None, [f"{option} {run_dir}: {e}"]
    return from_saved(saved), []


def validate_robustness_args(args) -> list[str]:
    """Problems of ``score-robustness`` arguments (``run_dir``, ``seeds``)."""
    _, problems = _source_run("--run-dir", args.run_dir)
    if args.seeds < 1:
        problems.append(f"--seeds {args.seeds}: must be >= 1")
    return problems


def transfer_run_dir(args) -> str:
    """Where ``score-transfer`` writes: ``--run-dir``, else ``<checkpoint>-transfer``."""
    return args.run_dir or args.checkpoint.rstrip("/") + "-transfer"


def _growing() -> str:
    return ", ".join(n for n in registry.algorithm_names() if registry.entry(n).grows)


def validate_transfer_args(args) -> list[str]:
    """Problems of ``score-transfer`` arguments (``checkpoint``, ``env``, ``subspaces``,
    ``total_steps``, ``run_dir``, ``eval_episodes``, ``compare_scratch``, ``new_actor_prior``:
    only for an algorithm that adds actors, ``freeze_critic_encoder``: only for a SCORE
    critic with encoders of its own): the source run, the
    target sub-spaces (known, not empty, every trained one included, at least one new) and the
    fine-tuning run's own configuration and directories."""
    src, problems = _source_run("--checkpoint", args.checkpoint)
    if args.total_steps is not None and args.total_steps < 1:
        problems.append(f"--total-steps {args.total_steps}: must be >= 1")
    if args.eval_episodes < 1:
        problems.append(f"--eval-episodes {args.eval_episodes}: must be >= 1")
    names, name_problems = _subspace_names(args.subspaces)
    problems += name_problems
    if src is None:
        return problems
    if src.algo in registry.algorithm_names() and not registry.entry(src.algo).grows:
        return problems + [
            f"--checkpoint {args.checkpoint} was trained with {src.algo!r}, whose networks are "
            "tied to the sub-spaces it was trained on, so it cannot grow by unseen ones "
            f"(score-transfer takes runs of {_growing()})"
        ]
    if args.env is not None and args.env != src.env:
        problems.append(f"--env {args.env}: the checkpoint was trained on {src.env!r}")
    if (
        args.new_actor_prior
        and src.algo in registry.algorithm_names()
        and registry.entry(src.algo).fixed_width
    ):
        problems.append(
            f"--new-actor-prior: {src.algo!r} is a fixed-width baseline, so the transfer adds no "
            "new actors: the new sub-spaces' heads come from the subset run, which started them "
            "untrained (and trained them as --single.transfer-variant says)"
        )
    if args.freeze_critic_encoder and not critic_owns_encoders(src):
        problems.append(
            f"--freeze-critic-encoder: the checkpoint's critic has no encoders of its own to "
            f"freeze (only SCORE's has, unless --score.critic.no-finetune-asrl made it read the "
            f"frozen HVAE); it was trained with {src.algo!r}"
        )
    run_dir = transfer_run_dir(args)
    if os.path.abspath(run_dir) == os.path.abspath(args.checkpoint):
        problems.append(f"--run-dir {run_dir}: is the trained run's own directory")
    fine_tune = dataclasses.replace(
        src,
        subspaces=None,
        run_dir=run_dir,
        resume=None,
        total_steps=src.total_steps if args.total_steps is None else max(args.total_steps, 1),
        eval_episodes=max(args.eval_episodes, 1),
    )
    train_problems, raw = _check_train(fine_tune)
    problems += train_problems
    if args.compare_scratch:
        problems += _run_dir_problems(run_dir + "-scratch", "--run-dir (with --compare-scratch)")
    if raw is None:
        return problems
    space = raw.space
    problems += _unknown_subspaces(names, space)
    target = set(names) if names else set(space.names)
    trained = src.agent_names() or space.names
    left_out = [n for n in trained if n not in target]
    if left_out and not name_problems:
        problems.append(
            f"--subspaces {args.subspaces} leaves out the trained sub-space(s) "
            f"{', '.join(left_out)}: the target must include every sub-space the run was "
            "trained on"
        )
    elif not left_out and target <= set(trained):
        problems.append(
            f"--subspaces {args.subspaces or '(all)'}: no new sub-space to transfer to (the run "
            f"was trained on {', '.join(trained)})"
        )
    return problems


__all__ = [
    "UsageError",
    "prepare_train",
    "resume_config",
    "validate_robustness_args",
    "validate_train_config",
    "validate_transfer_args",
]
