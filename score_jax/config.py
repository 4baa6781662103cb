"""Run configuration: frozen dataclasses exposed on the command line with tyro.

Shape-changing fields (network sizes, number of envs, batch size) are static; numbers that
only scale arrays (learning rates, gamma, tau, DropNode rate) are fed as arrays where the
compiled code allows it.
"""

from __future__ import annotations

import ast
import dataclasses
from typing import Literal

from score_jax.baselines.marl_config import MarlConfig
from score_jax.baselines.single_config import SingleAgentConfig
from score_jax.score import ScoreConfig
from score_jax.trainer import OffPolicyConfig

EnvName = Literal["greenhouse", "spider", "probe"]
AlgoName = Literal["score", "sac", "ppo", "hppo", "isac", "maddpg", "maac", "qmix"]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Train an algorithm on a composite-action environment (default: SCORE on the greenhouse)."""

    env: EnvName = "greenhouse"
    """Environment name."""
    algo: AlgoName = "score"
    """Algorithm."""
    total_steps: int = 0
    """Environment steps (transitions) to train for; 0 = the environment's preset."""
    seed: int = 0
    """Seed of every random stream (ASRL data, init, exploration, replay, evaluation)."""
    run_dir: str = ""
    """Where checkpoints, metrics.csv and plots go; empty = runs/<env>-<algo>-s<seed>."""
    resume: str = ""
    """Resume the run in this directory from its latest checkpoint (the saved config is used)."""
    subspaces: str = ""
    """Comma-separated sub-spaces to control (the others stay at their defaults); empty = all."""
    env_options: tuple[str, ...] = ()
    """Environment options as key=value (e.g. reward=profit discrete_hours=False)."""
    checkpoint_every: int = 0
    """Save a checkpoint every this many environment steps; 0 = about 10 per run."""
    action_repeat: int = 0
    """Environment steps one decision is held for (``envs.wrappers.ActionRepeat``); 0 = the
    environment's suggestion (greenhouse: 8 days, others 1). Step counts (``--total-steps``,
    ``--eval-every``, replay) count decisions; returns always sum the environment's rewards."""
    eval_episodes: int = 10
    """Episodes per evaluation (each a full season / episode)."""
    eval_every: int = -1
    """Evaluate the deterministic policy every this many env steps; -1 = the environment's preset
    (greenhouse: every 16k steps, spider: 20k), 0 = only at the end."""
    keep_best: bool = True
    """Keep the best-evaluated policy in <run-dir>/best and report it next to the last one (the
    end-of-run robustness sweep and render use it); needs periodic evaluations."""
    robustness_seeds: int = 10
    """Seeds per setting of the robustness sweep run at the end (0 = skip it)."""
    render: bool = False
    """Spider only: render an episode of the trained policy to <run-dir>/render (PNG + GIF)."""
    render_steps: int = 300
    """Steps of the rendered episode."""
    quiet: bool = False
    """No progress bar."""
    data_parallel: bool = True
    """Shard environments and batches over all devices when there are several."""
    transfer_from: str = ""
    """(Set by transfer.py) the run this one was grown from (§4.3)."""
    transfer_new: str = ""
    """(Set by transfer.py) comma-separated sub-spaces that are new in this run: their actors train from scratch."""
    finetune_old_actors: bool = False
    """In a transfer run, also fine-tune the actors of the sub-spaces seen before (default: frozen)."""
    off_policy: OffPolicyConfig = OffPolicyConfig()
    """Rollout, replay and update schedule."""
    score: ScoreConfig = ScoreConfig()
    """SCORE networks, ASRL and SAC settings."""
    marl: MarlConfig = MarlConfig()
    """Multi-agent baselines (isac, maddpg, maac, qmix): sizes, learning rates, exploration."""
    single: SingleAgentConfig = SingleAgentConfig()
    """Single-agent baselines trained by brax (sac, ppo, hppo) and the transfer variant of fixed-width baselines."""

    def env_overrides(self) -> dict:
        """``env_options`` parsed into keyword overrides (values as Python literals when possible)."""
        out = {}
        for item in self.env_options:
            if "=" not in item:
                raise ValueError(f"env option {item!r} must look like key=value")
            key, value = item.split("=", 1)
            try:
                out[key] = ast.literal_eval(value)
            except (ValueError, SyntaxError):
                out[key] = value
        return out

    def agent_names(self) -> tuple[str, ...]:
        return tuple(x.strip() for x in self.subspaces.split(",") if x.strip())


# Budgets that finish on a laptop CPU (see README for the measured wall times).
PRESET_TOTAL_STEPS = {"greenhouse": 144_000, "spider": 200_000, "probe": 4_000}  # decisions (see action_repeat)


def resolved_total_steps(cfg: TrainConfig) -> int:
    return cfg.total_steps or PRESET_TOTAL_STEPS[cfg.env]


def resolved_action_repeat(cfg: TrainConfig, env) -> int:
    """``cfg.action_repeat``, or the environment's suggestion (``env.action_repeat``, else 1)."""
    if cfg.action_repeat < 0:
        raise ValueError(f"action_repeat must be >= 0 (0 = the environment's suggestion), got {cfg.action_repeat}")
    return cfg.action_repeat or int(getattr(env, "action_repeat", 1))


PRESET_EVAL_EVERY = {"greenhouse": 16_000, "spider": 20_000, "probe": 0}


def resolved_eval_every(cfg: TrainConfig) -> int:
    """Env steps between deterministic evaluations (0 = only at the end)."""
    return PRESET_EVAL_EVERY.get(cfg.env, 0) if cfg.eval_every < 0 else cfg.eval_every


def to_dict(cfg) -> dict:
    return dataclasses.asdict(cfg)


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
