"""Run configuration: frozen dataclasses exposed on the command line with tyro, and their
resolution into the numbers a run uses.

Shape-changing fields (network sizes, number of envs, batch size) are static; numbers that
only scale arrays (learning rates, gamma, tau, DropNode rate) are fed as arrays where the
compiled code allows it. ``None`` is the one spelling of "the environment's preset" (or "the
default"); ``resolve`` turns a ``TrainConfig`` and the environment's hints into a ``RunSpec``
once, at the start of a run, and everything below reads the ``RunSpec``.
"""

from __future__ import annotations

import copy
import dataclasses
import os
from typing import Literal

import numpy as np

import envs
from score_jax import registry
from score_jax.agents.brax.config import SingleAgentConfig
from score_jax.agents.marl.config import MarlConfig
from score_jax.agents.score.config import ScoreConfig


@dataclasses.dataclass(frozen=True)
class OffPolicyConfig:
    """The shared off-policy trainer: rollout, replay and update schedule (shape-changing fields
    are static; the rest are fed as arrays where it matters)."""

    num_envs: int = 8
    """Parallel environments (the ``data`` axis)."""
    batch_size: int = 128
    """Transitions per gradient update."""
    replay_capacity: int = 50_000
    """Ring buffer size in transitions."""
    learning_starts: int = 400
    """Transitions collected with the uniform random policy before updates start."""
    updates_per_step: int | None = None
    """Gradient updates per vectorised environment step; None = the environment's suggestion
    (``env.hints.updates_per_step``: 1 on the greenhouse, 2 elsewhere)."""
    steps_per_epoch: int = 20
    """Vectorised environment steps per jitted epoch call."""
    n_step: int | None = None
    """Steps per TD target (n-step returns, drawn from the one-step replay at sampling time:
    ``agents.replay.replay_sample_nstep``); an episode's end or a terminal shortens it. 1 = the
    paper's one-step target; None = the environment's suggestion (``env.hints.n_step``: 3 on
    the greenhouse, 1 elsewhere)."""
    train_failures: int = 0
    """Controlled sub-spaces that fail at every collection step (redrawn each step; 0 = none).
    The environment receives the failure-mode replacement and the critic masks those agents."""
    train_failure_mode: int = 0
    """Failure mode of ``train_failures``: 0 default, 1 random, 2 last (``FailureMode``)."""
    exploration_hold: int | None = None
    """Steps an environment keeps the same exploration noise (the policy's random draw, i.e. the
    Gaussian noise and Gumbel draws relative to the current mean and logits), redrawn every
    this many steps of its episode and at every reset, as gSDE's ``sde_sample_freq`` (Raffin et
    al. 2021), counted in the environment's own steps (``EnvState.t``). 1 = fresh noise every
    step; None = the environment's suggestion (``env.hints.exploration_hold``)."""
    exploration_shift: float = 0.0
    """Std of a shift shared by all continuous dims of a sub-space, added (before the tanh) to
    the stochastic policy's action when collecting data and held like its noise
    (``exploration_hold``). The policy's own Gaussian noise is independent per dim, so the mean
    of a sub-space's 24 hourly setpoints barely moves; the shift explores that mean directly
    (``run.exploration.shift_continuous``). Behaviour only: the losses never see it. In-process
    learners only (brax's SAC/PPO/H-PPO keep their own noise, as for the hold). 0 = off."""


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Train an algorithm on a composite-action environment (default: SCORE on the greenhouse)."""

    env: str = "greenhouse"
    """Environment name (a registered environment: greenhouse, spider, probe, or one added with
    ``envs.register``)."""
    algo: str = "score"
    """Algorithm (``score_jax.registry``: score, isac, maddpg, maac, qmix, sac, ppo, hppo)."""
    total_steps: int | None = None
    """Decisions (transitions) to train for; None = the environment's preset."""
    seed: int = 0
    """Seed of every random stream (ASRL data, init, exploration, replay, evaluation)."""
    num_seeds: int = 1
    """Independent runs of seeds ``seed .. seed + num_seeds - 1`` in one compiled program (a
    leading seed axis of the training state; each seed has its own ASRL, init, exploration,
    replay and evaluation streams). brax-trained algorithms (sac, ppo, hppo) train their seeds
    one after another: brax's ``train()`` cannot be vmapped."""
    run_dir: str | None = None
    """Where checkpoints, metrics.csv and plots go; None = runs/<env>-<algo>-s<seed>."""
    resume: str | None = None
    """Resume the run in this directory from its newest usable checkpoint, with its saved
    configuration: ``--total-steps N`` extends it to N decisions; any other option that differs
    from the saved one is refused (``run.validate``)."""
    subspaces: str | None = None
    """Comma-separated sub-spaces to control (the others stay at their defaults); None = all."""
    env_options: tuple[str, ...] = ()
    """Environment options as key=value (e.g. reward=profit discrete_hours=False)."""
    checkpoint_every: int | None = None
    """Save a checkpoint every this many decisions; None = about 10 per run."""
    action_repeat: int | None = None
    """Environment steps one decision is held for (``envs.wrappers.ActionRepeat``); None = the
    environment's suggestion (greenhouse: 8 days, others 1). Step counts (``--total-steps``,
    ``--eval-every``, replay) count decisions; returns always sum the environment's rewards."""
    action_width: int | None = None
    """Padded action width of every agent; None = the environment's full max_dim (so transfer
    can add sub-spaces of any width)."""
    default_prior: bool = True
    """Every algorithm's untrained policy starts at the sub-spaces' defaults (the safe values a
    failed controller falls back to) and explores around them. SCORE, ISAC, MADDPG, MAAC: the
    actors' Gaussian mean is offset by atanh(default) and the default choice's logit by
    --score.actor.prior-logit / --marl.actor.prior-logit; SAC, PPO: the policy's output bias
    starts at the same offsets of the flat action; H-PPO: its heads' biases (logit bonus
    --single.prior-logit); QMIX: the candidate grid is centred on the default, whose Q starts
    --marl.qmix-prior-q ahead. --no-default-prior: none of these; every policy starts
    mid-range with uniform choices (QMIX: a grid centred mid-range, all Q equal)."""
    eval_episodes: int = 10
    """Episodes per evaluation (each a full season / episode)."""
    eval_every: int | None = None
    """Evaluate the deterministic policy every this many decisions; None = the environment's
    preset (greenhouse: every 16k, spider: 20k), 0 = only at the end."""
    keep_best: bool = True
    """Keep the best-evaluated policy in <run-dir>/best and report it next to the last one (the
    end-of-run robustness sweep and render use it); needs periodic evaluations."""
    robustness_seeds: int = 10
    """Seeds per setting of the robustness sweep run at the end (0 = skip it)."""
    planned_references: bool = True
    """The end-of-run report (and ``score-eval``) also evaluates the references the environment
    finds by planning on its own simulator (greenhouse: the best constant schedule and the best
    open-loop schedule for the run's decision interval; a search of about a minute on a CPU the
    first time per environment and code version, then read from ~/.cache/score-jax)."""
    render: bool = False
    """Spider only: render an episode of the trained policy to <run-dir>/render (PNG + GIF)."""
    render_steps: int = 300
    """Steps of the rendered episode."""
    quiet: bool = False
    """No progress bar."""
    data_parallel: bool = True
    """Shard over all devices when there are several: whole seeds when ``num_seeds`` is a
    multiple of the device count, else each seed's environments and batches."""
    cpu_devices: int | None = None
    """On a CPU, XLA host devices to split the machine into (``score-train`` sets
    ``--xla_force_host_platform_device_count`` before JAX starts); None = for a run of several
    seeds, one per core when the seeds divide evenly over them (XLA runs a program on about one
    core), else 1. Ignored when XLA_FLAGS already sets a device count."""
    distributed: bool = False
    """Train over several processes (hosts): each one runs this same command and they join
    through ``jax.distributed.initialize`` before JAX starts (CPU: gloo collectives). The seeds
    are sharded over the devices of every process (``--num-seeds`` must be a multiple of their
    count); only process 0 writes files and prints. The run directory must be on a filesystem
    every process sees."""
    coordinator_address: str | None = None
    """With ``--distributed``: HOST:PORT of process 0, where the processes meet; None =
    $JAX_COORDINATOR_ADDRESS, else what jax detects (Slurm, Open MPI, Kubernetes, Cloud TPU)."""
    num_processes: int | None = None
    """With ``--distributed``: how many processes take part; None = $JAX_NUM_PROCESSES, else
    what jax detects."""
    process_id: int | None = None
    """With ``--distributed``: this process's index, 0 .. num_processes - 1 (0 writes the run's
    files); None = $JAX_PROCESS_ID, else what jax detects."""
    track: tuple[Literal["csv", "tensorboard", "wandb"], ...] = ("csv",)
    """Metric writers, several allowed; csv (<run-dir>/metrics.csv) is always on. tensorboard:
    event files in <run-dir>/tensorboard; wandb: a Weights & Biases run in <run-dir>/wandb
    (both from ``pip install -e .[tracking]``)."""
    wandb_project: str = "score-jax"
    """W&B project of ``--track wandb``."""
    wandb_mode: Literal["offline", "online"] | None = None
    """W&B mode; None = $WANDB_MODE, else offline (no network or login needed; ``wandb sync``
    uploads the run later)."""
    compile_cache: bool = True
    """JAX's persistent compilation cache (a per-user directory, ~/.cache/score-jax/xla, or
    $SCORE_JAX_CACHE/xla; an already set $JAX_COMPILATION_CACHE_DIR wins), so a second start
    of the same configuration skips most compilation."""
    describe: bool = False
    """Print the environment's sub-spaces (name, kind, dims, range, default, units) and presets,
    then exit."""
    off_policy: OffPolicyConfig = OffPolicyConfig()
    """Rollout, replay and update schedule."""
    score: ScoreConfig = ScoreConfig()
    """SCORE networks, ASRL and SAC settings."""
    marl: MarlConfig = MarlConfig()
    """Multi-agent baselines (isac, maddpg, maac, qmix): sizes, learning rates, exploration."""
    single: SingleAgentConfig = SingleAgentConfig()
    """Single-agent baselines trained by brax (sac, ppo, hppo) and the transfer variant of
    fixed-width baselines."""

    def env_overrides(self) -> dict:
        """``env_options`` parsed into keyword overrides of ``envs.make``, each value typed
        against the environment's option (``envs.parse_options``: ``discrete_hours=false`` is
        False, ``=maybe`` an error); a ValueError lists every problem."""
        values, problems = envs.parse_options(self.env, self.env_options)
        if problems:
            raise ValueError("; ".join(problems))
        return values

    def agent_names(self) -> tuple[str, ...]:
        """The sub-spaces named by ``subspaces`` (empty: all of them)."""
        if self.subspaces is None:
            return ()
        return tuple(x.strip() for x in self.subspaces.split(",") if x.strip())

    def algorithm_settings(self):
        """This run's section of the configuration for its algorithm's builder."""
        return getattr(self, registry.entry(self.algo).settings)


@dataclasses.dataclass(frozen=True)
class TransferSpec:
    """A fine-tuning run grown from a trained run (§4.3), set by ``transfer.py``.

    ``source``: the trained run's directory; ``new``: the sub-spaces that are new (their actors
    train from scratch); ``finetune_old_actors``: also fine-tune the actors seen before;
    ``new_actor_prior``: the new actors start at their sub-spaces' defaults (the default
    prior); False = untrained, mid-range with uniform choices (§4.3);
    ``finetune_critic_encoder``: SCORE's critic also fine-tunes its own encoders (its copy of
    the HVAE's, ``CriticConfig.finetune_asrl``), as in training; False keeps them frozen with
    the HVAE as §4.3 writes it (``score-transfer --freeze-critic-encoder``).
    """

    source: str
    new: tuple[str, ...]
    finetune_old_actors: bool = False
    new_actor_prior: bool = False
    finetune_critic_encoder: bool = False

    @classmethod
    def from_dict(cls, d: dict) -> TransferSpec:
        """A saved spec (``dataclasses.asdict``); one saved before ``new_actor_prior`` existed
        gave its new actors the default prior, so a missing key reads True; one saved before
        ``finetune_critic_encoder`` existed kept the encoders frozen."""
        return cls(
            d["source"],
            tuple(d["new"]),
            bool(d["finetune_old_actors"]),
            bool(d.get("new_actor_prior", True)),
            bool(d.get("finetune_critic_encoder", False)),
        )


def critic_owns_encoders(cfg: TrainConfig) -> bool:
    """Whether ``cfg``'s run is SCORE with a critic that owns encoders (its copy of the HVAE's,
    ``CriticConfig.finetune_asrl``, or its own from scratch without ASRL), which a transfer run
    fine-tunes unless ``score-transfer --freeze-critic-encoder``; a critic that reads the
    frozen HVAE (``--score.critic.no-finetune-asrl``) has none."""
    critic = cfg.score.critic
    return cfg.algo == "score" and (critic.finetune_asrl or not critic.asrl)


def prior_agents(cfg: TrainConfig, names, transfer: TransferSpec | None = None):
    """``[n]`` bool: which of the agents (sub-space ``names``) start at their defaults.

    Every agent follows ``cfg.default_prior``, except the new agents of a transfer run, which
    follow ``transfer.new_actor_prior``; for a fixed-width baseline (brax SAC / PPO / H-PPO)
    they are False: their heads come from the subset run, which starts the heads of the
    sub-spaces it does not control without the prior (``agents.brax.agents.build``).
    """
    old = bool(cfg.default_prior)
    if transfer is None:
        return np.full(len(names), old)
    new_prior = transfer.new_actor_prior and not registry.entry(cfg.algo).fixed_width
    new = set(transfer.new)
    return np.asarray([new_prior if n in new else old for n in names], bool)


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """The numbers a run uses, resolved once from its ``TrainConfig`` and environment.

    Attributes:
      run_dir: where everything goes.
      total_steps, eval_every, checkpoint_every: decisions (steps of the action-repeated env).
      action_repeat: environment steps per decision; exploration_hold: steps an exploration
        draw is held; updates_per_step: gradient updates per vectorised step; n_step: steps
        per TD target; width: the
        agents' padded action width.
      steps_per_epoch: decisions per jitted epoch of the off-policy trainer.
    """

    run_dir: str
    total_steps: int
    eval_every: int
    checkpoint_every: int
    action_repeat: int
    exploration_hold: int
    updates_per_step: int
    n_step: int
    width: int
    steps_per_epoch: int

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def default_run_dir(cfg: TrainConfig) -> str:
    return cfg.run_dir or os.path.join("runs", f"{cfg.env}-{cfg.algo}-s{cfg.seed}")


def resolve(cfg: TrainConfig, env) -> RunSpec:
    """``cfg``'s presets resolved against ``env`` (the environment before any action repeat)."""
    hints = env.hints
    total = hints.total_steps if cfg.total_steps is None else cfg.total_steps
    repeat = hints.pick("action_repeat", cfg.action_repeat)
    hold = hints.pick("exploration_hold", cfg.off_policy.exploration_hold)
    updates = hints.pick("updates_per_step", cfg.off_policy.updates_per_step)
    n_step = hints.pick("n_step", cfg.off_policy.n_step)
    width = env.space.max_dim if cfg.action_width is None else cfg.action_width
    if width < env.space.max_dim:
        raise ValueError(
            f"action_width={width} is smaller than the environment's max_dim={env.space.max_dim}"
        )
    spe = cfg.off_policy.num_envs * cfg.off_policy.steps_per_epoch
    ckpt = (
        cfg.checkpoint_every
        if cfg.checkpoint_every is not None
        else max(spe, (total // 10) // spe * spe)
    )
    return RunSpec(
        run_dir=default_run_dir(cfg),
        total_steps=int(total),
        eval_every=int(hints.eval_every if cfg.eval_every is None else cfg.eval_every),
        checkpoint_every=int(ckpt),
        action_repeat=repeat,
        exploration_hold=hold,
        updates_per_step=updates,
        n_step=n_step,
        width=int(width),
        steps_per_epoch=int(spe),
    )


def environment_names() -> list[str]:
    return envs.registered_names()


def to_dict(cfg) -> dict:
    return dataclasses.asdict(cfg)


# Options whose default changed, with the value a run saved before the change used: a saved
# configuration that lacks the key ran with that value, so it rebuilds (and restores) as it ran.
CHANGED_DEFAULTS: dict[tuple[str, ...], object] = {
    ("score", "critic", "finetune_asrl"): False,
    ("off_policy", "n_step"): 1,  # runs saved before n-step returns trained with one-step targets
}


# Options whose None means "the environment's hint" (``EnvHints``), with their key in a saved
# run's ``resolved`` record: a hint can change, so a saved run is rebuilt with what it resolved to.
HINTED_OPTIONS: dict[tuple[str, ...], str] = {
    ("action_repeat",): "action_repeat",
    ("off_policy", "exploration_hold"): "exploration_hold",
    ("off_policy", "updates_per_step"): "updates_per_step",
    ("off_policy", "n_step"): "n_step",
}


def from_saved(d: dict) -> TrainConfig:
    """A run's saved ``TrainConfig`` (``to_dict`` output, possibly written by an older version):
    keys missing from it take the value they had then (``CHANGED_DEFAULTS``), the others the
    current defaults; options it left to the environment's hints (``HINTED_OPTIONS``) take the
    values they resolved to (``d["resolved"]``), so a resumed run trains as it did even after
    the environment's suggestion changed."""
    d = copy.deepcopy(d)
    resolved = d.get("resolved") or {}
    for path, key in HINTED_OPTIONS.items():
        node = d
        for name in path[:-1]:
            node = node.get(name) if isinstance(node, dict) else None
        if isinstance(node, dict) and node.get(path[-1]) is None and resolved.get(key) is not None:
            node[path[-1]] = int(resolved[key])
    for path, old in CHANGED_DEFAULTS.items():
        node = d
        for key in path[:-1]:
            node = node.get(key) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.setdefault(path[-1], old)
    return from_dict(TrainConfig, d)


def from_dict(cls, d: dict):
    """Rebuild a (nested) frozen dataclass from ``to_dict`` output, ignoring unknown keys."""
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in d:
            continue
        value = d[f.name]
        if dataclasses.is_dataclass(f.default) and isinstance(value, dict):
            value = from_dict(type(f.default), value)
        elif isinstance(value, list):
            value = tuple(tuple(v) if isinstance(v, list) else v for v in value)
        kwargs[f.name] = value
    return cls(**kwargs)
