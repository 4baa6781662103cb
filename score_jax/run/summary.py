"""What a run says about itself: the header printed at its start, the resolved block of its
``config.json``, and the environment description of ``score-train --describe``.

The header is printed before any heavy set-up (SCORE's ASRL stage), one line per item: backend,
devices, run directory, environment, algorithm, seed, budget, evaluation schedule, checkpoint
interval, action repeat, tracking and the compilation cache. It also refuses tracking that
cannot work (``--track wandb`` without wandb installed) before minutes are spent.
"""

from __future__ import annotations

import dataclasses
import os

import jax

import envs
from envs.wrappers import with_action_repeat
from score_jax import registry
from score_jax.run.compile_cache import cache_status
from score_jax.run.config import (
    RunSpec,
    TrainConfig,
    TransferSpec,
    default_run_dir,
    prior_agents,
    resolve,
)
from score_jax.run.writers import check_kinds


def tracking_kinds(cfg: TrainConfig) -> tuple[str, ...]:
    """``cfg.track`` with csv first and no repeats (csv is always on)."""
    return tuple(dict.fromkeys(("csv", *cfg.track)))


def _tracking(cfg: TrainConfig, run_dir: str) -> str:
    where = {
        "csv": os.path.join(run_dir, "metrics.csv"),
        "tensorboard": os.path.join(run_dir, "tensorboard"),
        "wandb": (
            f"project {cfg.wandb_project}, "
            f"{cfg.wandb_mode or os.environ.get('WANDB_MODE') or 'offline'}, "
            f"{os.path.join(run_dir, 'wandb')}"
        ),
    }
    return "; ".join(f"{k} ({where[k]})" for k in tracking_kinds(cfg))


def _devices(cfg: TrainConfig) -> str:
    devices = jax.devices()
    kinds = sorted({d.device_kind for d in devices})
    line = f"{len(devices)} x {', '.join(kinds)}"
    if jax.process_count() > 1:
        line += f" over {jax.process_count()} processes"
    if len(devices) > 1:
        if not cfg.data_parallel:
            line += ", one used (--no-data-parallel)"
        elif cfg.num_seeds % len(devices) == 0:
            line += ", seeds sharded (whole seeds per device)"
        else:
            line += ", each seed's envs and batches sharded (data parallel)"
    return line


def _evaluation(cfg: TrainConfig, spec: RunSpec) -> str:
    if not spec.eval_every:
        return f"at the end only, {cfg.eval_episodes} episodes"
    n = spec.total_steps // spec.eval_every
    kept = "; the best policy kept in <run dir>/best" if cfg.keep_best else ""
    return (
        f"every {spec.eval_every} decisions ({n} evaluation{'s' if n != 1 else ''}), "
        f"{cfg.eval_episodes} episodes each{kept}"
    )


def header_lines(cfg: TrainConfig, spec: RunSpec, env) -> list[str]:
    """The start-of-run header of ``cfg`` resolved to ``spec`` on ``env`` (before any action
    repeat), one ``name: value`` line per item."""
    space = env.space
    agents = cfg.agent_names()
    controlled = f"controls {', '.join(agents)}" if agents else "controls all"
    options = " ".join(f"{k}={v}" for k, v in cfg.env_overrides().items())
    in_process = registry.entry(cfg.algo).in_process
    checkpoints = (
        f"every {spec.checkpoint_every} decisions (and at the end)"
        if in_process
        else "the final policy (brax trains in its own loop)"
    )
    items = [
        ("backend", f"{jax.default_backend()} (jax {jax.__version__})"),
        ("devices", _devices(cfg)),
        ("run dir", os.path.abspath(spec.run_dir) + (" (resuming)" if cfg.resume else "")),
        (
            "env",
            f"{cfg.env}: {space.n} sub-spaces, {space.total_dim} action dims, "
            f"{env.episode_length}-step episodes; {controlled}"
            + (f"; options {options}" if options else ""),
        ),
        ("algo", cfg.algo),
        (
            "seed",
            str(cfg.seed)
            if cfg.num_seeds == 1
            else f"{cfg.seed}..{cfg.seed + cfg.num_seeds - 1} "
            f"({cfg.num_seeds} seeds in one program)",
        ),
        (
            "budget",
            f"{spec.total_steps} decisions = {spec.total_steps * spec.action_repeat} env steps, "
            f"{cfg.off_policy.num_envs} envs",
        ),
        ("evaluation", _evaluation(cfg, spec)),
        ("checkpoints", checkpoints),
        (
            "action repeat",
            f"{spec.action_repeat} env step{'s' if spec.action_repeat > 1 else ''} per decision",
        ),
        (
            "updates",
            f"{spec.updates_per_step} per vectorised step, batch {cfg.off_policy.batch_size}, "
            f"{spec.n_step}-step TD targets"
            if in_process
            else "brax's own schedule",
        ),
        ("tracking", _tracking(cfg, spec.run_dir)),
        ("compile cache", cache_status()),
    ]
    width = max(len(k) for k, _ in items) + 1
    return [f"{k + ':':<{width}s} {v}" for k, v in items]


def announce(cfg: TrainConfig, run_dir: str | None = None, log=print) -> RunSpec:
    """Check that the tracking ``cfg`` asks for can work, then print its header through ``log``
    (one line per item). Returns the resolved ``RunSpec``. ValueError for unknown or uninstalled
    tracking, an unknown environment or an invalid preset."""
    check_kinds(cfg.track, installed=True)
    env = envs.make(cfg.env, **cfg.env_overrides())
    spec = resolve(cfg, env)
    spec = dataclasses.replace(spec, run_dir=run_dir or default_run_dir(cfg))
    for line in header_lines(cfg, spec, env):
        log(line)
    return spec


def resolved_config(
    cfg: TrainConfig, spec: RunSpec, env, agent_index, transfer: TransferSpec | None = None
) -> dict:
    """Every preset of ``cfg`` as the number the run uses: ``spec`` (budget, evaluation and
    checkpoint intervals, action repeat, exploration hold, width), the env steps of the budget,
    the controlled sub-spaces, those whose policy starts at the default (``default_prior``,
    ``prior_agents``: a transfer run's new agents may differ) and the learners' reward scale.
    ``env``: the run's (action-repeated) environment."""
    names = [env.space.names[int(i)] for i in agent_index]
    prior = prior_agents(cfg, names, transfer)
    out = {
        **spec.to_dict(),
        "env_steps": spec.total_steps * spec.action_repeat,
        "agents": names,
        "default_prior": [n for n, on in zip(names, prior, strict=True) if on],
    }
    settings = cfg.algorithm_settings()
    for field in ("reward_scale", "reward_scaling"):  # SAC-family / brax settings
        if hasattr(settings, field):
            explicit = getattr(settings, field)
            out["reward_scale"] = float(env.hints.reward_scale if explicit is None else explicit)
            break
    return out


def describe_environment(name: str, overrides: dict | None = None) -> str:
    """``score-train --describe``: the environment's sizes, presets and sub-spaces."""
    env = envs.make(name, **(overrides or {}))
    hints = env.hints
    repeated = with_action_repeat(env, hints.action_repeat)
    evaluation = (
        f"evaluation every {hints.eval_every} decisions"
        if hints.eval_every
        else "evaluation at the end only"
    )
    lines = [
        f"environment {name!r}: {env.space.n} sub-spaces, {env.space.total_dim} action dims "
        f"(padded [{env.space.n}, {env.space.max_dim}]), observation {env.observation_size}, "
        f"episode {env.episode_length} steps",
        f"presets: budget {hints.total_steps} decisions, {evaluation}, action repeat "
        f"{hints.action_repeat} "
        f"({repeated.episode_length} decisions per episode), exploration hold "
        f"{hints.exploration_hold}, {hints.updates_per_step} update(s) per step, "
        f"{hints.n_step}-step TD targets, reward scale "
        f"{hints.reward_scale:g}",
        f"reference policies: {', '.join(['random', 'default', *env.reference_policies()])}",
        "",
        env.space.describe(),
        "",
        f"--subspaces takes a comma-separated subset of: {','.join(env.space.names)}",
    ]
    return "\n".join(lines)
