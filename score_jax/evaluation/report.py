"""End-of-run report: the learned policy against reference policies, and the learning curve."""

from __future__ import annotations

import csv
import os

import jax
import numpy as np

from score_jax.core.spaces import agents_to_env_action
from score_jax.run.best_policy import has_best, restore_best
from score_jax.run.checkpoint import dump_json
from score_jax.run.episodes import evaluate, reference_policies


def final_evaluation(
    run, n_episodes: int, log=print, learned: dict | None = None, path: str | None = None
) -> dict:
    """Mean/std return of the trained policy (the last one, and the best-evaluated one when the
    run kept it) and of each reference, over the same seeds; printed as a table and written to
    ``evaluation.json`` in the run directory.

    ``learned``: ``{label: agent state}`` to evaluate instead of the last and best policies;
    ``path``: where the JSON goes instead."""
    key = jax.random.PRNGKey(run.config.seed + 20_000)
    if learned is None:
        learned = {run.config.algo: run.state.agent}
        if has_best(run.run_dir):
            agent, meta = restore_best(run.run_dir, run.state.agent)
            learned[f"{run.config.algo} (best, step {meta['step']})"] = agent
    rows = {}
    for name, agent in learned.items():  # one compiled evaluator, the parameters an argument
        r = np.asarray(run.evaluate(agent, n_episodes, key=key).returns)
        rows[name] = _stats(r)
    for name, act in reference_policies(
        run.env, run.agent_index, run.algo.off_policy.width
    ).items():
        r = np.asarray(
            jax.jit(
                lambda k, act=act: evaluate(run.env, act, k, n_episodes, run.agent_index).returns
            )(key)
        )
        rows[name] = _stats(r)
    width = max(10, *(len(k) for k in rows))
    lines = [
        f"{'policy':<{width}s} {'return mean':>12s} {'std':>9s} {'min':>10s} {'max':>10s}   "
        f"({n_episodes} episodes)"
    ]
    lines += [
        f"{k:<{width}s} {v['mean']:12.2f} {v['std']:9.2f} {v['min']:10.2f} {v['max']:10.2f}"
        for k, v in rows.items()
    ]
    log("\n".join(lines))
    dump_json(
        path or os.path.join(run.run_dir, "evaluation.json"),
        {"episodes": n_episodes, "returns": rows},
    )
    return rows


def _stats(r: np.ndarray) -> dict:
    return {
        "mean": float(r.mean()),
        "std": float(r.std()),
        "min": float(r.min()),
        "max": float(r.max()),
    }


def plot_learning_curve(csv_path: str, png_path: str, title: str = "") -> None:
    """Episode return (training episodes, and deterministic evaluations if any) against env
    steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    steps = np.array([float(r["env_steps"]) for r in rows])
    ret = np.array([float(r["episode_return"]) for r in rows])
    ev = np.array([float(r["eval_return"]) for r in rows])
    fig, ax = plt.subplots(figsize=(7, 4))
    ok = ~np.isnan(ret)
    if ok.any():
        ax.plot(steps[ok], ret[ok], ".", alpha=0.35, label="training episodes")
        window = max(1, ok.sum() // 20)
        smooth = np.convolve(ret[ok], np.ones(window) / window, mode="valid")
        ax.plot(steps[ok][window - 1 :], smooth, "-", lw=2, label=f"moving mean ({window})")
    if (~np.isnan(ev)).any():
        ax.plot(steps[~np.isnan(ev)], ev[~np.isnan(ev)], "o-", label="evaluation (deterministic)")
    _save(fig, ax, png_path, title, "episode return")


def plot_curves(curves: dict[str, str], path: str, title: str) -> None:
    """Smoothed training-episode return against env steps for several metrics.csv files
    (Figs. 6b/8b)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for label, csv_path in curves.items():
        with open(csv_path) as f:
            rows = list(csv.DictReader(f))
        # runs trained inside brax (sac, ppo, hppo) log no training episodes: plot their evaluations
        column = (
            "episode_return" if any(r["episode_return"] != "nan" for r in rows) else "eval_return"
        )
        rows = [r for r in rows if r[column] != "nan"]
        steps = np.array([float(r["env_steps"]) for r in rows])
        ret = np.array([float(r[column]) for r in rows])
        if len(ret):
            w = max(1, len(ret) // 15)
            ax.plot(
                steps[w - 1 :],
                np.convolve(ret, np.ones(w) / w, mode="valid"),
                label=label if column == "episode_return" else f"{label} (evaluations)",
            )
    _save(fig, ax, path, title, "episode return (training episodes)")


def _save(fig, ax, path: str, title: str, ylabel: str) -> None:
    import matplotlib.pyplot as plt

    ax.set_xlabel("decisions (steps of the action-repeated env)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def render_policy(
    run, steps: int, out_dir: str, log=print, png: bool = True, mp4: bool = False
) -> dict:
    """Render a deterministic episode of the trained policy (Spider) to PNG frames (``png``), a
    GIF and, with ``mp4``, an MP4 (GIF only, with a note, when imageio-ffmpeg is missing).
    Returns the written paths by format."""
    # deferred: imports MuJoCo's renderer
    from envs.spider.render import mp4_unavailable_reason, render_rollout

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
