"""Tiny configurations shared by the learner tests (small networks, short ASRL, few steps)."""

import dataclasses

from score_jax.agents.score.config import ScoreConfig
from score_jax.networks.actor import ActorConfig
from score_jax.networks.critic import CriticConfig
from score_jax.networks.hvae import HVAEConfig
from score_jax.run.config import OffPolicyConfig, TrainConfig

TINY_SCORE = ScoreConfig(
    hvae=HVAEConfig(obs_embed_dim=16, space_embed_dim=8, latent_dim=8, hidden=32, predict_steps=2),
    critic=CriticConfig(hidden=32, agent_dim=32, hyper_hidden=32),
    actor=ActorConfig(hidden=(64, 64)),
    asrl_k=4,
    asrl_j=4,
    asrl_steps=20,
    # the probe tests were calibrated with these (the greenhouse defaults differ)
    actor_lr=3e-4,
    critic_lr=3e-4,
    discrete_entropy_scale=0.3,
)
TINY_OFF_POLICY = OffPolicyConfig(
    num_envs=8,
    batch_size=64,
    replay_capacity=20_000,
    learning_starts=200,
    steps_per_epoch=25,
    updates_per_step=1,
)


def tiny_config(run_dir: str, **overrides) -> TrainConfig:
    base = TrainConfig(
        env="probe",
        total_steps=1000,
        run_dir=str(run_dir),
        quiet=True,
        checkpoint_every=400,
        off_policy=TINY_OFF_POLICY,
        score=TINY_SCORE,
    )
    return dataclasses.replace(base, **overrides)


def tiny_cli_args(run_dir: str, total_steps: int = 1000) -> list[str]:
    """The same configuration as ``tiny_config`` spelled as train.py arguments."""
    o = TINY_OFF_POLICY
    return [
        "--env",
        "probe",
        "--total-steps",
        str(total_steps),
        "--run-dir",
        str(run_dir),
        "--quiet",
        "--checkpoint-every",
        "400",
        "--off-policy.num-envs",
        str(o.num_envs),
        "--off-policy.batch-size",
        str(o.batch_size),
        "--off-policy.replay-capacity",
        str(o.replay_capacity),
        "--off-policy.learning-starts",
        str(o.learning_starts),
        "--off-policy.steps-per-epoch",
        str(o.steps_per_epoch),
        "--off-policy.updates-per-step",
        str(o.updates_per_step),
        "--score.actor-lr",
        str(TINY_SCORE.actor_lr),
        "--score.critic-lr",
        str(TINY_SCORE.critic_lr),
        "--score.discrete-entropy-scale",
        str(TINY_SCORE.discrete_entropy_scale),
        "--score.hvae.obs-embed-dim",
        "16",
        "--score.hvae.space-embed-dim",
        "8",
        "--score.hvae.latent-dim",
        "8",
        "--score.hvae.hidden",
        "32",
        "--score.hvae.predict-steps",
        "2",
        "--score.critic.hidden",
        "32",
        "--score.critic.agent-dim",
        "32",
        "--score.critic.hyper-hidden",
        "32",
        "--score.actor.hidden",
        "64",
        "64",
        "--score.asrl-k",
        "4",
        "--score.asrl-j",
        "4",
        "--score.asrl-steps",
        "20",
    ]
