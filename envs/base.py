"""The CompositeEnv protocol, the state every environment returns, and the environment's hints.

An environment is a pure-function object: ``reset(key) -> EnvState`` and
``step(state, action) -> EnvState`` with ``action`` the learner's normalised, padded
``[n, max_dim]`` array (see ``score_jax.core.spaces``). ``jax.jit(jax.vmap(env.step))`` works
for every environment. Simulator parameters (weather, crop and physics parameters) are pytree
fields of the environment object, so a batch of variants is ``jax.vmap`` over environments.

Subclass ``CompositeEnv`` to inherit the defaults of its optional members (``hints``,
``reference_policies``, ``planned_references``); ``envs.make`` refuses an object that lacks a
member of the protocol.
"""

from __future__ import annotations

import ast
import collections.abc
import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import jax
from flax import struct

from score_jax.core.spaces import CompositeSpace


@struct.dataclass
class EnvState:
    """State of one environment (add leading axes for batches).

    Attributes:
      sim: the simulator's own state (an environment-specific pytree).
      obs: ``[observation_size]`` float32 observation, shared by all sub-spaces.
      reward: ``[]`` float32 reward of the last step (0 after reset).
      done: ``[]`` float32, 1.0 when the episode ended at the last step (terminal or time limit).
      truncated: ``[]`` float32, 1.0 when it ended by the time limit only (bootstrap through it).
      t: ``[]`` int32 steps taken in this episode.
      metrics: an environment-specific pytree of per-step diagnostics (e.g. yield, energy).
      info: extras of wrappers, as brax keeps them in ``state.info`` (``AutoReset`` puts the
        observation its step reached, before any reset, under ``"final_obs"``).
    """

    sim: Any
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    truncated: jax.Array
    t: jax.Array
    metrics: Any
    info: dict = struct.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class EnvHints:
    """What an environment suggests to the learners, and its training presets.

    Attributes:
      reward_scale: rewards are multiplied by this in the learners' targets (keeps Q-values of
        order 100 whatever the reward's units).
      action_repeat: environment steps a learner's decision is held for (``ActionRepeat``).
      exploration_hold: environment steps an exploration draw is held for (gSDE-style).
      updates_per_step: gradient updates per vectorised step of the off-policy trainer.
      n_step: steps per TD target of the off-policy learners (1 = one-step targets).
      total_steps: preset training budget, in decisions (steps of the action-repeated env).
      eval_every: preset interval of deterministic evaluations, in decisions (0 = at the end).
    """

    reward_scale: float = 1.0
    action_repeat: int = 1
    exploration_hold: int = 1
    updates_per_step: int = 2
    n_step: int = 1
    total_steps: int = 100_000
    eval_every: int = 0

    def pick(self, name: str, given: int | None) -> int:
        """``given``, or this hint when it is None (a learner's option left to the environment);
        a ValueError names the option when the result is below 1."""
        value = int(getattr(self, name) if given is None else given)
        if value < 1:
            raise ValueError(f"{name} must be >= 1, got {value}")
        return value


# act(state) -> normalised [n, max_dim] action for ONE (unbatched) state: a scripted policy.
ReferencePolicy = Callable[["EnvState"], jax.Array]


@runtime_checkable
class CompositeEnv(Protocol):
    """What the learner, the baselines and the evaluation protocols need from an environment.

    Attributes (plain attributes or properties):
      name: the registry name; space: the composite action space; observation_size: the
      length of ``EnvState.obs``; episode_length: steps of a full episode.
    """

    name: str
    space: CompositeSpace
    observation_size: int
    episode_length: int

    def reset(self, key: jax.Array) -> EnvState: ...

    def step(self, state: EnvState, action: jax.Array) -> EnvState: ...

    @property
    def hints(self) -> EnvHints:
        """Reward scale, action repeat, exploration hold and presets (defaults: ``EnvHints()``)."""
        return EnvHints()

    def reference_policies(self) -> Mapping[str, ReferencePolicy]:
        """Scripted policies the end-of-run report compares with (e.g. a grower heuristic)."""
        return {}

    def planned_references(self, action_repeat: int = 1) -> Mapping[str, ReferencePolicy]:
        """Reference policies found by planning on the simulator itself, for decisions held
        ``action_repeat`` steps (greenhouse: the best constant and open-loop schedules). May
        be expensive the first time (a search); the report asks only when told to."""
        return {}


def missing_members(env: object) -> list[str]:
    """Members of the ``CompositeEnv`` protocol that ``env`` lacks (empty if it satisfies it)."""
    members = (
        "name",
        "space",
        "observation_size",
        "episode_length",
        "reset",
        "step",
        "hints",
        "reference_policies",
        "planned_references",
    )
    return [m for m in members if not hasattr(env, m)]


def config_fields(config_cls, prefix: str = "") -> dict[str, dataclasses.Field]:
    """Every option of a (nested) config dataclass by its dotted name (``physics.timestep``)."""
    out = {}
    for f in dataclasses.fields(config_cls):
        if dataclasses.is_dataclass(f.default):
            out.update(config_fields(type(f.default), f"{prefix}{f.name}."))
        else:
            out[prefix + f.name] = f
    return out


def build_config(config_cls, overrides: dict, base=None):
    """``config_cls(**overrides)`` (or ``base`` with them replaced); a dotted key
    (``physics.timestep``) sets a field of a nested config. Unknown keys raise a ValueError
    that lists the accepted ones."""
    fields = {f.name: f for f in dataclasses.fields(config_cls)}
    flat, nested = {}, {}
    for key, value in overrides.items():
        head, dot, rest = key.partition(".")
        if dot:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[key] = value
    unknown = sorted(
        {k for k in flat if k not in fields}
        | {k for k in nested if k not in fields or not dataclasses.is_dataclass(fields[k].default)}
    )
    if unknown:
        raise ValueError(
            f"unknown option(s) {unknown} for {config_cls.__name__}; "
            f"accepted: {sorted(config_fields(config_cls))}"
        )
    for head, sub in nested.items():
        inner = flat.get(head, getattr(base, head) if base is not None else fields[head].default)
        flat[head] = build_config(type(inner), sub, base=inner)
    return dataclasses.replace(base, **flat) if base is not None else config_cls(**flat)


# --- options given as text (the command line's ``--env-options key=value``) -----------------

_TRUE = ("true", "1", "yes", "on")
_FALSE = ("false", "0", "no", "off")


def option_types(config_cls, prefix: str = "") -> dict[str, Any]:
    """Every option of a (nested) config dataclass by its dotted name, with its type annotation
    resolved (``{"physics.timestep": float, "reward": Literal[...], ...}``)."""
    hints = typing.get_type_hints(config_cls)
    out = {}
    for f in dataclasses.fields(config_cls):
        if dataclasses.is_dataclass(f.default):
            out.update(option_types(type(f.default), f"{prefix}{f.name}."))
        else:
            out[prefix + f.name] = hints[f.name]
    return out


def describe_type(tp) -> str:
    """``tp`` in words, for error messages (``"true or false"``, ``"one of 'a', 'b'"``)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join("none" if a is type(None) else describe_type(a) for a in args)
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (tuple, list, collections.abc.Sequence):
        if len(args) == 2 and args[1] is Ellipsis:
            return f"comma-separated {describe_type(args[0])} values"
        if args:
            return f"{len(args)} comma-separated values ({', '.join(map(describe_type, args))})"
        return "comma-separated values"
    return {
        bool: "true or false",
        int: "an integer",
        float: "a finite number",
        str: "a string",
    }.get(tp, getattr(tp, "__name__", str(tp)))


def _unquote(text: str) -> str:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    return text


def parse_option(text: str, tp) -> Any:
    """The value of ``text`` for an option annotated ``tp``: bool (true/false, 1/0, yes/no, on/off,
    any case), int, float (finite), str (quotes optional), ``Literal`` choices, tuples
    (comma-separated, brackets optional) and unions such as ``X | None`` (``none``). Raises a
    ValueError saying what was expected."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    bad = ValueError(f"expected {describe_type(tp)}, got {text!r}")
    if origin in (typing.Union, types.UnionType):
        if type(None) in args and _unquote(text).lower() in ("none", "null"):
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return parse_option(text, a)
            except ValueError:
                pass
        raise bad
    if origin is typing.Literal:
        for choice in args:
            try:
                value = parse_option(text, type(choice))
            except ValueError:
                continue
            if value == choice:
                return choice
        raise bad
    if origin in (tuple, list, collections.abc.Sequence):
        inner = text.strip()
        if inner[:1] + inner[-1:] in ("()", "[]"):
            inner = inner[1:-1]
        items = [x for x in (s.strip() for s in inner.split(",")) if x] if inner.strip() else []
        if len(args) == 2 and args[1] is Ellipsis:
            kinds = [args[0]] * len(items)
        elif args:
            if len(items) != len(args):
                raise bad
            kinds = list(args)
        else:
            kinds = [str] * len(items)
        return tuple(parse_option(x, k) for x, k in zip(items, kinds, strict=True))
    word = _unquote(text)
    if tp is bool:
        if word.lower() in _TRUE:
            return True
        if word.lower() in _FALSE:
            return False
        raise bad
    if tp is int:
        try:
            return int(word)
        except ValueError:
            raise bad from None
    if tp is float:
        try:
            value = float(word)
        except ValueError:
            raise bad from None
        if not math.isfinite(value):
            raise bad
        return value
    if tp is str:
        return word
    try:  # any other annotation: a Python literal, else the text itself
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def parse_options(
    items: Sequence[str], types_: Mapping[str, Any] | None, owner: str = "environment"
) -> tuple[dict, list[str]]:
    """``key=value`` texts -> ``(overrides, problems)``: each value parsed against
    ``types_[key]`` (``option_types``); ``types_`` None = untyped (Python literals when possible,
    else the text). Every problem (malformed item, unknown or repeated key, bad value) is one
    message; the overrides hold the items that parsed."""
    out, problems, seen = {}, [], set()
    for item in items:
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq or not key:
            problems.append(f"{owner} option {item!r} must look like key=value")
            continue
        if key in seen:
            problems.append(f"{owner} option {key!r} is given twice")
            continue
        seen.add(key)
        if types_ is None:
            try:
                out[key] = ast.literal_eval(text)
            except (ValueError, SyntaxError):
                out[key] = text
            continue
        if key not in types_:
            problems.append(
                f"unknown {owner} option {key!r}; accepted: {', '.join(sorted(types_))}"
            )
            continue
        try:
            out[key] = parse_option(text, types_[key])
        except ValueError as e:
            problems.append(f"{owner} option {key}: {e}")
    return out, problems
