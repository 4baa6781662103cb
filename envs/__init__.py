"""Environment registry: ``envs.make(name, **overrides) -> CompositeEnv``.

Environments are imported lazily so that using the greenhouse never imports MuJoCo.
"""

from __future__ import annotations

import importlib
from typing import Callable

from envs.base import CompositeEnv, EnvState

# name -> "module:factory"; the factory takes keyword overrides and returns a CompositeEnv.
_REGISTRY: dict[str, str | Callable[..., CompositeEnv]] = {
    "greenhouse": "envs.greenhouse.env:make_greenhouse",
    "spider": "envs.spider.env:make_spider",
    "probe": "envs.probe:make_probe",
}


def register(name: str, factory: str | Callable[..., CompositeEnv]) -> None:
    """Add an environment: ``factory`` is a callable or a ``"module:function"`` string."""
    _REGISTRY[name] = factory


def registered_names() -> list[str]:
    return sorted(_REGISTRY)


def make(name: str, **overrides) -> CompositeEnv:
    """Build the environment called ``name``; ``overrides`` go to its config.

    Raises:
      ValueError: for an unknown name (the message lists the known ones) or an unknown
        override (the message lists the accepted ones).
    """
    if name not in _REGISTRY:
        raise ValueError(f"unknown environment {name!r}; known environments: {registered_names()}")
    factory = _REGISTRY[name]
    if isinstance(factory, str):
        module, func = factory.split(":")
        factory = getattr(importlib.import_module(module), func)
    return factory(**overrides)


__all__ = ["CompositeEnv", "EnvState", "make", "register", "registered_names"]
