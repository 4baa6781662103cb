"""Evaluate and watch a saved run (``score-eval``): its best or last policy against the reference
policies, a table, and what the environment can show of it.

    score-eval --run-dir runs/greenhouse-score-s0 [--policy best|last] [--episodes N] [--render]

Writes into ``<run-dir>/eval-<policy>/`` (or ``--out``; ``eval-last`` when ``best`` was asked
for and the run kept no best policy):
- ``evaluation.json`` and ``evaluation.md``: mean, std, min and max return of the policy and of
  each reference policy (random, default, and the environment's scripted ones such as the
  greenhouse expert), over the same seeds as the end-of-run report;
- greenhouse: ``season.png``, the season of the policy next to the references (cumulative
  harvest, temperature, CO2, energy; decisions held for the run's action repeat), and the
  season totals in ``evaluation.md``;
- Spider with ``--render``: ``render/rollout.gif`` and ``render/rollout.mp4`` (MP4 needs
  imageio-ffmpeg, ``pip install -e .[render]``; without it the GIF alone, with a note).
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp

from envs.wrappers import unwrapped
from score_jax.core.spaces import agents_to_env_action
from score_jax.evaluation.report import final_evaluation, render_policy
from score_jax.run.best_policy import has_best, restore_best
from score_jax.run.build import Run, restore_run, with_best_policy
from score_jax.run.episodes import reference_policies


def _load(run_dir: str, policy: str, log) -> tuple[Run, str, str]:
    """The run with the requested policy in place (every seed's), the policy it holds (``best``,
    or ``last`` when the run kept no best) and its label (``score (best, step N)`` for one seed,
    ``score (best per seed)`` for several)."""
    run = restore_run(run_dir, log=log, policy="last")
    algo = run.config.algo
    if policy == "best":
        if has_best(run.run_dir):
            _, meta = restore_best(run.run_dir, run.state.agent)
            run = with_best_policy(run, log=log)
            steps = [s for s in meta["best_steps"] if s is not None]
            where = f"step {steps[0]}" if run.num_seeds == 1 and steps else "per seed"
            return run, "best", f"{algo} (best, {where})"
        log(f"{run_dir} kept no best policy (no periodic evaluations): using the last one")
    return run, "last", f"{algo} (last, step {int(max(run.state.env_steps.tolist()))})"


def markdown_table(rows: dict, n_episodes: int) -> str:
    """``final_evaluation``'s rows as a Markdown table."""
    lines = [
        f"Episode returns over {n_episodes} episodes (the same seeds for every policy):",
        "",
        "| policy | return mean | std | min | max | share of open-loop |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for k, v in rows.items():
        share = f"{100 * v['share_of_open_loop']:.1f}%" if "share_of_open_loop" in v else ""
        lines.append(
            f"| {k} | {v['mean']:.2f} | {v['std']:.2f} | {v['min']:.2f} | {v['max']:.2f} "
            f"| {share} |"
        )
    return "\n".join(lines)


def held_rollout(
    env, policies: dict, agents: dict, agent_index, repeat: int, key: jax.Array
) -> tuple:
    """One season of the greenhouse ``env`` (not action-repeated) under each policy, each decision
    held ``repeat`` days as in training and evaluation, in ONE compiled program:
    ``(metrics, reward, action)`` with a leading ``[n_policies, days]`` on every leaf, in the
    order of ``policies`` (``metrics``: daily ``GreenhouseMetrics``; ``reward [n, days]``;
    ``action [n, days, space.n, space.max_dim]``: the normalised environment action applied on
    each day, a fresh decision on days ``0, repeat, 2 repeat, ...``).

    ``policies[name](agents[name])`` is a batched learner policy (``run.algo.policy`` and its
    agent state, or a reference policy and None); the agent states are arguments of the
    program, in which every policy drives its own copy of the season (one vmapped
    ``env.step`` for all of them) from the same start.
    """
    space, names = env.space, list(policies)
    n = len(names)

    @jax.jit
    def seasons(agents, key_reset, key_run):
        acts = [policies[name](agents[name]) for name in names]
        state = jax.vmap(env.reset)(jnp.broadcast_to(key_reset, (n, *key_reset.shape)))
        held = jnp.broadcast_to(space.default_action(), (n, space.n, space.max_dim))

        def day(carry, key_t):
            state, held = carry
            own = [jax.tree.map(lambda x, k=k: x[k : k + 1], state) for k in range(n)]
            fresh = jnp.concatenate(
                [
                    agents_to_env_action(space, act(s, key_t), agent_index)
                    for act, s in zip(acts, own, strict=True)
                ]
            )
            action = jnp.where((state.t % repeat == 0)[:, None, None], fresh, held)
            state = jax.vmap(env.step)(state, action)
            return (state, action), (state.metrics, state.reward, action)

        keys = jax.random.split(key_run, env.episode_length)
        _, out = jax.lax.scan(day, (state, held), keys)
        return jax.tree.map(lambda x: jnp.moveaxis(x, 0, 1), out)  # [n, days, ...]

    key_reset, key_run = jax.random.split(key)
    return seasons({name: agents[name] for name in names}, key_reset, key_run)


def held_seasons(
    env, policies: dict, agents: dict, agent_index, repeat: int, key: jax.Array
) -> dict:
    """``held_rollout``'s seasons as ``{name: season.SeasonTrace}`` of daily metrics."""
    from envs.greenhouse.season import FIRST_HARVEST_KG, SeasonTrace

    metrics, reward, _ = held_rollout(env, policies, agents, agent_index, repeat, key)
    out = {}
    for k, name in enumerate(policies):
        m = jax.tree.map(lambda x, k=k: x[k], metrics)
        reached = m.cumulative_yield >= FIRST_HARVEST_KG
        first = jnp.where(jnp.any(reached), jnp.argmax(reached) + 1, -1).astype(jnp.int32)
        out[name] = SeasonTrace(m, reward[k], jnp.sum(reward[k]), first)
    return out


SEASON_COLUMNS = {
    "yield_kg_m2": "yield kg/m²",
    "return": "return",
    "first_harvest_day": "first harvest (day)",
    "heating_mj_m2": "heating MJ/m²",
    "electricity_kwh_m2": "lamps kWh/m²",
    "co2_kg_m2": "CO2 kg/m²",
    "profit_eur_m2": "profit €/m²",
}


def _season_table(totals: dict) -> str:
    """``{policy: season.summarize(trace)}`` as a Markdown table."""
    lines = [
        "| policy | " + " | ".join(SEASON_COLUMNS.values()) + " |",
        "|---|" + "---:|" * len(SEASON_COLUMNS),
    ]
    for name, t in totals.items():
        lines.append(f"| {name} | " + " | ".join(f"{t[c]:.2f}" for c in SEASON_COLUMNS) + " |")
    return "\n".join(lines)


def _is_greenhouse(env) -> bool:
    from envs.greenhouse.env import GreenhouseEnv

    return isinstance(unwrapped(env), GreenhouseEnv)


def season_report(run: Run, label: str, out_dir: str, log=print) -> tuple[str, str, dict]:
    """Greenhouse: ``season.png`` with the policy's season next to the reference policies', and
    the season totals. Returns (the figure's path, the totals as a Markdown table,
    ``{policy: season.summarize(trace)}``)."""
    from envs.greenhouse.season import plot_season, summarize

    env = unwrapped(run.env)
    key = jax.random.PRNGKey(run.config.seed + 30_000)
    first = run.for_seed(0) if run.batched else run  # the season plot shows the first seed
    if run.num_seeds > 1:
        label = f"{label}, seed {first.seeds[0]}"
    policies, agents = {label: first.algo.policy}, {label: first.state.agent}
    for name, act in reference_policies(
        run.env, run.agent_index, run.algo.off_policy.width, run.config.planned_references
    ).items():
        policies[name], agents[name] = (lambda _, act=act: act), None
    traces = held_seasons(env, policies, agents, run.agent_index, run.spec.action_repeat, key)
    path = os.path.join(out_dir, "season.png")
    plot_season(
        traces,
        path,
        f"{label} vs references, decisions held {run.spec.action_repeat} days ({run.run_dir})",
    )
    totals = {name: summarize(tr) for name, tr in traces.items()}
    summary = _season_table(totals)
    log(summary)
    log(f"season plot: {path}")
    return path, summary, totals


def evaluate_saved_run(
    run_dir: str,
    policy: str = "best",
    episodes: int | None = None,
    render: bool = False,
    render_steps: int | None = None,
    out_dir: str | None = None,
    log=print,
    planned_references: bool | None = None,
) -> dict:
    """Evaluate ``run_dir``'s ``policy`` (``best`` or ``last``) against the reference policies
    over ``episodes`` episodes (None = the run's ``--eval-episodes``) and write the files the
    module docstring lists. Returns ``{"rows", "files", "out_dir", "label", "season"}``
    (``season``: the greenhouse's season totals per policy, else None)."""
    if policy not in ("best", "last"):
        raise ValueError(f"policy must be 'best' or 'last', got {policy!r}")
    run, policy, label = _load(run_dir, policy, log)
    if planned_references is not None:  # else as the run's own report did
        config = dataclasses.replace(run.config, planned_references=planned_references)
        run = dataclasses.replace(run, config=config)
    n = int(episodes or run.config.eval_episodes)
    if n < 1:
        raise ValueError(f"episodes must be >= 1, got {n}")
    out = out_dir or os.path.join(run.run_dir, f"eval-{policy}")
    os.makedirs(out, exist_ok=True)
    files = {"json": os.path.join(out, "evaluation.json")}
    rows = final_evaluation(run, n, log=log, learned={label: run.state.agent}, path=files["json"])
    season = None
    md = [f"# {label} on {run.config.env}", "", f"Run: `{run.run_dir}`", ""]
    md.append(markdown_table(rows, n))
    if _is_greenhouse(run.env):
        files["season"], summary, season = season_report(run, label, out, log)
        md += ["", "Season totals (one season per policy, `season.png`):", "", summary]
    if render:
        if hasattr(run.env, "mj_model"):
            steps = int(render_steps or run.config.render_steps)
            written = render_policy(
                run, steps, os.path.join(out, "render"), log, png=False, mp4=True
            )
            files.update({k: str(v[0]) for k, v in written.items() if v})
        elif "season" in files:
            log("--render: the greenhouse has no body to draw; its season plot is season.png")
        else:
            log(f"--render: {run.config.env!r} has no body to draw (rendering needs the Spider)")
    files["markdown"] = os.path.join(out, "evaluation.md")
    with open(files["markdown"], "w") as f:
        f.write("\n".join(md) + "\n")
    log(f"wrote {', '.join(files.values())}")
    return {"rows": rows, "files": files, "out_dir": out, "label": label, "season": season}
