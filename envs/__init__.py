"""Environment registry: ``envs.make(name, **overrides) -> CompositeEnv``.

Environments are imported lazily so that using the greenhouse never imports MuJoCo.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from typing import Any

from envs import base
from envs.base import CompositeEnv, EnvHints, EnvState, missing_members
from score_jax.core.registry import LazyRegistry

# name -> "module:factory"; the factory takes keyword overrides and returns a CompositeEnv. A
# factory may declare ``config_class`` (the dataclass its overrides fill) and ``extra_options``
# (its other keyword options: name -> type annotation), so options given as text are typed.
_REGISTRY: LazyRegistry[Callable[..., CompositeEnv]] = LazyRegistry(
    "environment",
    {
        "greenhouse": "envs.greenhouse.env:make_greenhouse",
        "spider": "envs.spider.env:make_spider",
        "probe": "envs.probe:make_probe",
    },
)


def register(name: str, factory: str | Callable[..., CompositeEnv]) -> None:
    """Add an environment: ``factory`` is a callable or a ``"module:function"`` string."""
    _REGISTRY.register(name, factory)


def registered_names() -> list[str]:
    return _REGISTRY.names()


def factory(name: str) -> Callable[..., CompositeEnv]:
    """The factory registered under ``name`` (imported on first use). An unregistered name of the
    form ``"module:function"`` registers that factory under itself first, so a command line can
    name any importable environment (``score-train --env mypkg.envs:make_myenv``)."""
    if name not in _REGISTRY and isinstance(name, str) and name.count(":") == 1:
        module, attribute = name.split(":")
        try:
            fn = getattr(importlib.import_module(module), attribute)
        except (ImportError, AttributeError) as e:
            raise ValueError(f"cannot import the environment factory {name!r}: {e}") from e
        _REGISTRY.register(name, fn)
    return _REGISTRY.get(name)


def option_types(name: str) -> dict[str, Any] | None:
    """The options ``make(name, ...)`` accepts, by dotted name -> type annotation (the fields of
    its factory's ``config_class`` and its ``extra_options``); None when the factory declares
    no ``config_class`` (its options are then not typed)."""
    f = factory(name)
    config_class = getattr(f, "config_class", None)
    if config_class is None:
        return None
    return {**base.option_types(config_class), **getattr(f, "extra_options", {})}


def parse_options(name: str, items: Sequence[str]) -> tuple[dict, list[str]]:
    """``key=value`` texts (``--env-options``) -> ``(overrides for make(name, ...), problems)``,
    each value parsed against the option's type (``envs.base.parse_option``); one message per
    problem (malformed item, unknown or repeated option, value of the wrong type)."""
    return base.parse_options(items, option_types(name), owner=f"{name} env")


def make(name: str, **overrides) -> CompositeEnv:
    """Build the environment called ``name``; ``overrides`` go to its config.

    Raises:
      ValueError: for an unknown name (the message lists the known ones), an unknown
        override (the message lists the accepted ones), or a factory whose result does not
        satisfy the ``CompositeEnv`` protocol (the message names the missing members).
    """
    env = factory(name)(**overrides)
    missing = missing_members(env)
    if missing:
        raise ValueError(
            f"environment {name!r} does not satisfy the CompositeEnv protocol: it lacks {missing} "
            "(subclass envs.base.CompositeEnv to inherit the defaults of hints and "
            "reference_policies)"
        )
    return env


__all__ = [
    "CompositeEnv",
    "EnvHints",
    "EnvState",
    "factory",
    "make",
    "option_types",
    "parse_options",
    "register",
    "registered_names",
]
