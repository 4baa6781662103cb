"""End-of-run report: the learned policies (every seed) against the reference policies, and
the rendering of a trained Spider. In a distributed run every process evaluates (the seeds'
episodes run where the seeds are) and process 0 prints and writes."""

from __future__ import annotations

import dataclasses
import os

import jax
import numpy as np

from score_jax.core.spaces import agents_to_env_action
from score_jax.evaluation.stability import format_stability, lowest_after_exceeding
from score_jax.evaluation.stats import aggregate, format_interval
from score_jax.run import distributed
from score_jax.run.best_policy import has_best, restore_best
from score_jax.run.build import with_best_policy
from score_jax.run.checkpoint import dump_json
from score_jax.run.episodes import evaluate, reference_policies


def final_evaluation(
    run, n_episodes: int, log=print, learned: dict | None = None, path: str | None = None
) -> dict:
    """Returns of the trained policies (the last, and the best-evaluated ones when the run kept
    them) and of each reference policy; printed as a table and written to ``evaluation.json`` in
    the run directory.

    Every seed's policy is evaluated on ``n_episodes`` episodes (one vmapped call); a learned row
    holds the mean, std, min and max over all of them, the per-seed means, and their IQM, mean
    and median with 95% stratified-bootstrap intervals (``evaluation.stats``). The references
    are evaluated once, on the first seed's episodes. ``learned``: ``{label: seed-stacked agent
    state}`` to evaluate instead of the last and best policies; ``path``: where the JSON goes.
    At the end of a run (no ``learned``) it also reports each seed's training stability against
    the default policy (``evaluation.stability``; ``evaluation.json["stability"]``).
    """
    log = distributed.primary_only(log)
    keys = run.eval_keys(20_000)
    end_of_run = learned is None
    if learned is None:
        learned = {run.config.algo: run.state.agent}
        if has_best(run.run_dir):
            best = with_best_policy(run, log=lambda *a: None).state.agent
            _, meta = restore_best(run.run_dir, run.state.agent)
            steps = [s for s in meta["best_steps"] if s is not None]
            label = f"step {steps[0]}" if run.num_seeds == 1 and steps else "per seed"
            learned[f"{run.config.algo} (best, {label})"] = best
    rows = {}
    for name, agent in learned.items():  # one compiled evaluator, the parameters an argument
        returns = distributed.to_host(run.evaluate(agent, n_episodes, key=keys).returns)
        r = returns.reshape(run.num_seeds, -1)
        rows[name] = {**_stats(r), "per_seed": r.mean(axis=1).tolist(), "seeds": list(run.seeds)}
        if run.num_seeds > 1:
            agg = aggregate({name: r.mean(axis=1)}, reps=10_000, seed=run.config.seed)[name]
            rows[name]["over_seeds"] = {
                m: _interval(agg.metric(m)) for m in ("iqm", "mean", "median")
            }
    key = keys if not run.batched else keys[0]
    width = run.algo.off_policy.width
    planned = run.config.planned_references
    for name, act in reference_policies(run.env, run.agent_index, width, planned).items():
        episodes = lambda k, act=act: evaluate(run.env, act, k, n_episodes, run.agent_index)
        rows[name] = _stats(np.asarray(jax.jit(episodes)(key).returns))
    add_shares(rows, list(learned))
    log(_table(rows, n_episodes, run.num_seeds))
    out = {"episodes": n_episodes, "seeds": list(run.seeds), "returns": rows}
    if end_of_run and (stability := _stability(run, rows)) is not None:
        log(format_stability(stability, rows["default"]["mean"], "the default policy"))
        out["stability"] = {str(seed): s for seed, s in stability.items()}
    if distributed.is_primary():
        dump_json(path or os.path.join(run.run_dir, "evaluation.json"), out)
    return rows


def _stability(run, rows: dict) -> dict | None:
    """Per seed, the lowest moving-mean training return after it first beat the default policy
    (``evaluation.stability``), when the run logged training returns."""
    metrics = os.path.join(run.run_dir, "metrics.csv")
    if "default" not in rows or not os.path.exists(metrics):
        return None
    with open(metrics) as f:
        if "episode_return" not in f.readline().strip().split(","):
            return None
    return lowest_after_exceeding(metrics, rows["default"]["mean"])


# The upper reference a learned return is also given as a share of (the greenhouse's best
# open-loop schedule, ``envs.greenhouse.references``), when the report evaluates it.
UPPER_REFERENCE = "open-loop"


def add_shares(rows: dict, learned: list[str]) -> dict:
    """Give each learned row its mean as a share of the ``UPPER_REFERENCE`` row's mean
    (``share_of_open_loop``), when that row exists and its mean is positive (a share of a
    negative return, e.g. a season's loss, says nothing)."""
    top = rows.get(UPPER_REFERENCE)
    if top is not None and top["mean"] > 0:
        for name in learned:
            rows[name]["share_of_open_loop"] = rows[name]["mean"] / top["mean"]
    return rows


def _interval(iv) -> dict:
    return {"value": iv.value, "lo": iv.lo, "hi": iv.hi}


def _table(rows: dict, n_episodes: int, num_seeds: int) -> str:
    width = max(10, *(len(k) for k in rows))
    head = f"{'policy':<{width}s} {'return mean':>12s} {'std':>9s} {'min':>10s} {'max':>10s}"
    lines = [
        head + f"   ({n_episodes} episodes" + (f" x {num_seeds} seeds)" if num_seeds > 1 else ")")
    ]
    for k, v in rows.items():
        line = f"{k:<{width}s} {v['mean']:12.2f} {v['std']:9.2f} {v['min']:10.2f} {v['max']:10.2f}"
        if "share_of_open_loop" in v:
            line += f"   {100 * v['share_of_open_loop']:5.1f}% of open-loop"
        if "over_seeds" in v:
            iqm = v["over_seeds"]["iqm"]
            line += f"   IQM over seeds {format_interval(iqm['value'], iqm['lo'], iqm['hi'])}"
        lines.append(line)
    return "\n".join(lines)


def _stats(r: np.ndarray) -> dict:
    return {
        "mean": float(r.mean()),
        "std": float(r.std()),
        "min": float(r.min()),
        "max": float(r.max()),
    }


def render_policy(
    run, steps: int, out_dir: str, log=print, png: bool = True, mp4: bool = False
) -> dict:
    """Render a deterministic episode of the trained policy (Spider) to PNG frames (``png``), a
    GIF and, with ``mp4``, an MP4 (GIF only, with a note, when imageio-ffmpeg is missing).
    Returns the written paths by format."""
    # deferred: imports MuJoCo's renderer
    from envs.spider.render import mp4_unavailable_reason, render_rollout

    if distributed.multiprocess():  # process 0 renders from a host copy of the state
        run = dataclasses.replace(run, state=distributed.to_host(run.state))
        if not distributed.is_primary():
            return {}
    if run.batched:  # the first seed's policy
        run = run.for_seed(0)
    env, act = run.env, run.algo.policy(run.state.agent)
    if not hasattr(env, "mj_model"):
        raise ValueError(
            f"rendering needs a MuJoCo environment (spider); {env.name!r} has no body to draw"
        )

    def step(state, key):
        action = agents_to_env_action(env.space, act(state, key), run.agent_index)
        nxt = jax.vmap(env.step)(state, action)
        return nxt, (nxt.sim.data.qpos[0], nxt.done[0])

    state = jax.vmap(env.reset)(jax.random.PRNGKey(run.config.seed + 50_000)[None])
    _, (qpos, done) = jax.jit(
        lambda s: jax.lax.scan(step, s, jax.random.split(jax.random.PRNGKey(0), steps))
    )(state)
    qpos, done = np.asarray(qpos), np.asarray(done)
    end = int(np.argmax(done)) + 1 if done.any() else steps
    qpos = np.concatenate([np.asarray(state.sim.data.qpos), qpos[:end]])
    if mp4 and (reason := mp4_unavailable_reason()) is not None:
        log(f"no MP4 ({reason}); writing the GIF only")
        mp4 = False
    files = render_rollout(env.mj_model, qpos, out_dir, fps=1.0 / env.dt, png=png, mp4=mp4)
    videos = [str(p) for p in files.get("gif", []) + files.get("mp4", [])]
    log(f"rendered {len(qpos)} frames to {out_dir} ({', '.join(videos)})")
    return files
