"""The algorithm registry: ``--algo NAME`` -> which section of the configuration the algorithm
reads and its builder, imported on first use (listing the registry never imports brax).

The command line's choices (``--algo``, ``--env``) are derived from this registry and the
environment registry (``envs.registered_names``); ``register_algorithm`` adds one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from score_jax.agents.base import Algorithm
from score_jax.core.registry import LazyRegistry

# builder(settings, ctx: agents.base.BuildContext) -> Algorithm
Builder = Callable[..., Algorithm]


@dataclasses.dataclass(frozen=True)
class AlgorithmEntry:
    """``settings``: the ``TrainConfig`` field the builder receives (``score``, ``marl``,
    ``single``); ``builder``: the builder or its ``"module:function"`` path;
    ``in_process``: trained by the shared off-policy trainer (resumable), not brax's loop;
    ``grows``: its runs can grow by unseen sub-spaces (``Algorithm.grow``; checked before any
    work by ``score-transfer``); ``fixed_width``: its network has heads for every sub-space of
    the full space, so growing adds no new actors (the brax baselines: a subset run starts the
    heads of the sub-spaces it does not control untrained, without the default prior);
    ``variants``: it takes ``--single.transfer-variant``
    (``agents.variants``)."""

    settings: str
    builder: Builder | str
    in_process: bool = True
    grows: bool = True
    fixed_width: bool = False
    variants: bool = False


_ALGORITHMS: LazyRegistry[AlgorithmEntry] = LazyRegistry(
    "algorithm",
    {
        "score": AlgorithmEntry("score", "score_jax.agents.score.algorithm:make_score"),
        "isac": AlgorithmEntry("marl", "score_jax.agents.marl.isac:make_isac"),
        "maddpg": AlgorithmEntry("marl", "score_jax.agents.marl.maddpg:make_maddpg", variants=True),
        "maac": AlgorithmEntry("marl", "score_jax.agents.marl.maac:make_maac", variants=True),
        "qmix": AlgorithmEntry("marl", "score_jax.agents.marl.qmix:make_qmix", variants=True),
        "sac": AlgorithmEntry(
            "single",
            "score_jax.agents.brax.agents:make_sac",
            in_process=False,
            fixed_width=True,
            variants=True,
        ),
        "ppo": AlgorithmEntry(
            "single",
            "score_jax.agents.brax.agents:make_ppo",
            in_process=False,
            fixed_width=True,
            variants=True,
        ),
        "hppo": AlgorithmEntry(
            "single",
            "score_jax.agents.brax.hppo:make_hppo",
            in_process=False,
            fixed_width=True,
            variants=True,
        ),
    },
)


def register_algorithm(name: str, entry: AlgorithmEntry) -> None:
    """Add an algorithm (its builder may be a ``"module:function"`` path)."""
    _ALGORITHMS.register(name, entry)


def algorithm_names() -> list[str]:
    return _ALGORITHMS.names()


def entry(name: str) -> AlgorithmEntry:
    """The registry entry of ``name`` (a ValueError lists the known names)."""
    return _ALGORITHMS.get(name)


def builder(name: str) -> Builder:
    """The builder of ``name``, imported on first use."""
    e = entry(name)
    if isinstance(e.builder, str):
        return LazyRegistry("builder", {name: e.builder}).get(name)
    return e.builder
