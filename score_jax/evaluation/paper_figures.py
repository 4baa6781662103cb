"""The paper's figures that combine several runs (§5): pure data and plotting functions over
results already computed, for ``benchmarks/paper.py`` to call.

- Figs. 7/9, ``plot_robustness_panels``: every algorithm's robustness sweep
  (``robustness.json``, ``score_jax.evaluation.robustness``) in one panel per failure mode.
- Fig. 10, ``season_setpoints`` + ``plot_setpoints``: the temperature and CO2 setpoints of
  every decision of a greenhouse season at 0/6/12/18 h, one colour per policy (e.g. one trained
  with the ``"cumulative"`` yield reward and one with ``"profit"``).
- Fig. 11, ``robustness_shares`` + ``plot_ablation_robustness``: each ablation's return under
  failures as a share of its full-space return, stacked per number of failed sub-spaces.
- Fig. 12, ``collect_agent_embeddings`` + ``plot_agent_embeddings``: t-SNE of the critic's
  agent embeddings after p_w and after the GAT (``GraphCritic.embeddings``), coloured by
  sub-space, e.g. ``AL+HN`` (no ASRL) next to SCORE. t-SNE needs scikit-learn, the ``paper``
  extra (``pip install -e .[paper]``).
- Figs. 6b/8b, ``plot_transfer_curves``: fine-tuning curves on unseen sub-spaces from
  ``benchmarks/compare.py``'s results, mean and 95% band over seeds.

Every plot is written with matplotlib's Agg canvas (no display, the global backend untouched).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from score_jax.agents.variants import VARIANTS
from score_jax.core.spaces import agents_to_env_action
from score_jax.evaluation.curves import plot_band, t_interval
from score_jax.evaluation.saved_run import held_rollout
from score_jax.evaluation.stats import new_figure

MODE_TITLES = {"default": "default value", "random": "random value", "last": "previous value"}


def _colours(n: int) -> list[str]:
    return [f"C{i % 10}" for i in range(n)]


def _mode_index(result: dict, mode: str) -> int:
    modes = list(result["modes"])
    if mode not in modes:
        raise ValueError(f"failure mode {mode!r} is not in this sweep; it has {modes}")
    return modes.index(mode)


def _modes_of(results: Mapping[str, dict], modes: Sequence[str] | None) -> list[str]:
    if not results:
        raise ValueError("no robustness results to plot")
    if modes is not None:
        return list(modes)
    first = list(next(iter(results.values()))["modes"])
    return [m for m in first if all(m in r["modes"] for r in results.values())]


# --- Figs. 7/9: every algorithm's robustness, one panel per failure mode ------------------------


def robustness_band(result: dict, mode: str) -> dict:
    """Mean return and its 95% Student-t interval against the number of failed sub-spaces, for
    one failure mode of one ``robustness.json`` (``result``, as ``robustness.run_sweep`` writes
    it).

    Over the trained seeds (``per_trained_seed_mean [K, counts, modes]``) when there are K >= 2;
    a one-seed run's interval is over its evaluation episodes (``returns [counts, modes, E]``).
    Returns ``{"n_failed" [C], "mean" [C], "lo" [C], "hi" [C], "n", "over"}``; ``lo``/``hi``
    are None when there is a single sample per count.
    """
    j = _mode_index(result, mode)
    per_seed = result.get("per_trained_seed_mean")
    if per_seed is not None and len(per_seed) >= 2:
        stack, over = np.asarray(per_seed, float)[:, :, j], "trained seeds"
    else:
        stack, over = np.asarray(result["returns"], float)[:, j, :].T, "evaluation episodes"
    mean, lo, hi = t_interval(stack)
    return {
        "n_failed": np.asarray(result["n_failed"]),
        "mean": mean,
        "lo": lo,
        "hi": hi,
        "n": int(stack.shape[0]),
        "over": over,
    }


def plot_robustness_panels(
    results: Mapping[str, dict],
    path: str,
    title: str = "",
    modes: Sequence[str] | None = None,
) -> None:
    """Figs. 7/9 with every algorithm in one panel per failure mode: x = failed sub-spaces
    (redrawn every step), y = episode return, one line per algorithm (``results``:
    ``{label: robustness.json}``) with its 95% band (``robustness_band``). ``modes``: the
    panels (default: the modes every result has)."""
    modes = _modes_of(results, modes)
    bands = {m: {label: robustness_band(r, m) for label, r in results.items()} for m in modes}
    fig = new_figure(4.2 * len(modes) + 1.6, 3.8)
    axes = fig.subplots(1, len(modes), sharey=True, squeeze=False)[0]
    for ax, mode in zip(axes, modes, strict=True):
        for colour, (label, b) in zip(_colours(len(results)), bands[mode].items(), strict=True):
            ax.plot(b["n_failed"], b["mean"], "o-", color=colour, lw=1.8, ms=4, label=label)
            if b["lo"] is not None:
                ax.fill_between(b["n_failed"], b["lo"], b["hi"], color=colour, alpha=0.18, lw=0)
        ax.set_title(f"failure mode: {MODE_TITLES.get(mode, mode)}")
        ax.set_xlabel("failed sub-action spaces")
        ax.set_xticks(max((b["n_failed"] for b in bands[mode].values()), key=len))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("episode return (mean, 95% band)")
    overs = sorted({b["over"] for b in bands[modes[0]].values()})
    axes[-1].legend(
        fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), title=f"over {', '.join(overs)}"
    )
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=120)


# --- Fig. 10: greenhouse setpoints per decision -------------------------------------------------

SETPOINT_HOURS = (0, 6, 12, 18)


def season_setpoints(
    env,
    policies: dict,
    agents: dict,
    agent_index,
    repeat: int,
    key: jax.Array,
    hours: Sequence[int] = SETPOINT_HOURS,
) -> dict[str, dict]:
    """The temperature and CO2 setpoints of every decision of one greenhouse season, per policy.

    ``env`` is the greenhouse (not action-repeated); ``policies[name](agents[name])`` a batched
    learner policy (``run.algo.policy`` and one seed's agent state, or a reference policy and
    None), each decision held ``repeat`` days (``run.spec.action_repeat``) as in training; all
    policies run in one compiled program from the same start (``saved_run.held_rollout``).

    Returns ``{name: {"day" [D], "hours" [H], "temperature" [D, H] °C, "co2" [D, H] ppm}}``:
    ``day`` is the 0-based day of each of the D = ceil(days / repeat) decisions, the setpoints
    are the decoded physical hourly values (``actions.decode_action``) at ``hours``.
    """
    from envs.greenhouse.actions import decode_action

    hours = np.asarray(hours, int)
    if hours.ndim != 1 or not len(hours) or hours.min() < 0 or hours.max() > 23:
        raise ValueError(f"hours must be hours of the day in 0..23, got {hours.tolist()}")
    if repeat < 1:
        raise ValueError(f"repeat must be >= 1, got {repeat}")
    _, _, action = held_rollout(env, policies, agents, agent_index, repeat, key)
    days = np.arange(0, action.shape[1], repeat)
    decisions = action[:, days]  # [n_policies, D, space.n, max_dim]
    decode = lambda a: decode_action(env.space, a, 1)
    schedule = jax.vmap(jax.vmap(decode))(decisions)
    temp, co2 = np.asarray(schedule["temp_sp"]), np.asarray(schedule["co2_sp"])
    return {
        name: {
            "day": days,
            "hours": hours,
            "temperature": temp[k][:, hours],
            "co2": co2[k][:, hours],
        }
        for k, name in enumerate(policies)
    }


def plot_setpoints(setpoints: Mapping[str, dict], path: str, title: str = "") -> None:
    """Fig. 10: one panel per hour of the day, temperature setpoint (x) against CO2 setpoint (y)
    of every decision, one colour per policy (``season_setpoints``' output, e.g. ``{"yield
    reward": ..., "profit reward": ...}``)."""
    if not setpoints:
        raise ValueError("no setpoints to plot")
    hours = np.asarray(next(iter(setpoints.values()))["hours"])
    for name, s in setpoints.items():
        if not np.array_equal(np.asarray(s["hours"]), hours):
            raise ValueError(f"{name!r} has setpoints at hours {list(s['hours'])}, not {hours}")
    cols = 2 if len(hours) > 1 else 1
    rows = -(-len(hours) // cols)
    fig = new_figure(4.0 * cols + 1.8, 3.4 * rows)
    axes = np.atleast_1d(fig.subplots(rows, cols, sharex=True, sharey=True, squeeze=False)).ravel()
    for h, (ax, hour) in enumerate(zip(axes, hours, strict=False)):
        for colour, (name, s) in zip(_colours(len(setpoints)), setpoints.items(), strict=True):
            ax.scatter(
                s["temperature"][:, h], s["co2"][:, h], s=14, alpha=0.6, color=colour, label=name
            )
        ax.set_title(f"{int(hour):02d}:00")
        ax.grid(alpha=0.3)
    for ax in axes[len(hours) :]:
        ax.set_visible(False)
    for ax in axes[(rows - 1) * cols :]:
        ax.set_xlabel("temperature setpoint (°C)")
    for ax in axes[::cols]:
        ax.set_ylabel("CO2 setpoint (ppm)")
    axes[cols - 1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=120)


# --- Fig. 11: ablations' robustness as a share of their full-space return ------------------------


def robustness_shares(result: dict, mode: str) -> np.ndarray:
    """``[C]`` mean return with 0, 1, ..., C-1 failed sub-spaces over the full-space mean return
    (so entry 0 is 1), for one failure mode of one ``robustness.json`` (the pooled ``mean``).

    Raises ValueError when the full-space mean return is not positive: a share of it is then
    meaningless (shift the returns first).
    """
    mean = np.asarray(result["mean"], float)[:, _mode_index(result, mode)]
    if not mean[0] > 0:
        raise ValueError(
            f"the full-space mean return is {mean[0]:.4g}; shares of it need a positive return"
        )
    return mean / mean[0]


def plot_ablation_robustness(
    results: Mapping[str, dict],
    path: str,
    title: str = "",
    modes: Sequence[str] | None = None,
) -> None:
    """Fig. 11: one horizontal bar per ablation (``results``: ``{label: robustness.json}``), one
    panel per failure mode; the bar's segments are the share of the full-space return lost with
    1, 2, ... failed ("offline") sub-spaces (``1 - robustness_shares``, in %), stacked, so a
    longer bar is a less robust ablation. A count that gains return is drawn hatched to the
    left of 0."""
    modes = _modes_of(results, modes)
    counts = max(len(r["n_failed"]) for r in results.values())
    seg_colours = _colours(counts)
    fig = new_figure(4.2 * len(modes) + 1.8, 0.45 * len(results) + 1.6)
    axes = fig.subplots(1, len(modes), sharey=True, squeeze=False)[0]
    labels = list(results)
    for ax, mode in zip(axes, modes, strict=True):
        for i, label in enumerate(labels):
            try:
                lost = 100.0 * (1.0 - robustness_shares(results[label], mode))
            except ValueError as e:
                raise ValueError(f"{label!r}, mode {mode!r}: {e}") from None
            right = left = 0.0
            for k in range(1, len(lost)):
                v = float(lost[k])
                if v >= 0:
                    ax.barh(i, v, left=right, color=seg_colours[k], height=0.6)
                    right += v
                else:
                    ax.barh(i, v, left=left, color=seg_colours[k], height=0.6, hatch="//")
                    left += v
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_title(f"failure mode: {MODE_TITLES.get(mode, mode)}")
        ax.set_xlabel("share of the full-space return lost (%), stacked")
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(range(len(labels)), labels)
    axes[0].invert_yaxis()
    from matplotlib.patches import Patch

    handles = [Patch(color=seg_colours[k], label=f"{k} offline") for k in range(1, counts)]
    handles.append(Patch(facecolor="white", edgecolor="k", hatch="//", label="return gained"))
    axes[-1].legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=120)


# --- Fig. 12: t-SNE of the critic's agent embeddings --------------------------------------------


def collect_agent_embeddings(
    env, algo, agent, agent_index, key: jax.Array, n_episodes: int = 1
) -> dict[str, np.ndarray]:
    """The critic's agent embeddings at every step of deterministic episodes of ``algo``'s
    policy (a SCORE run or ablation: ``algo.networks.agent_embeddings``).

    ``env`` is the run's (action-repeated) environment, ``agent`` ONE seed's agent state
    (``run.for_seed(k).state.agent``). Every agent is active; the critic's inputs are the
    observation and the policy's own actions; the first twin critic's embeddings are kept.
    Returns ``{"p_w": [N, n_agents, agent_dim], "gat": [N, n_agents, agent_dim]}`` over the N
    steps at which an episode was still running (episodes x steps, step-major).
    """
    nets = getattr(algo, "networks", None)
    if not hasattr(nets, "agent_embeddings"):
        raise ValueError(
            f"{algo.name!r} has no graph critic with agent embeddings; only SCORE runs and its "
            "ablations (--algo score) have one"
        )
    agent_index = np.asarray(agent_index)
    n_agents = len(agent_index)

    @jax.jit
    def rollout(agent, key):
        act = algo.policy(agent)
        key_reset, key_run = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(key_reset, n_episodes))

        def step(carry, key_t):
            state, alive = carry
            action = act(state, key_t)  # [E, n_agents, width]
            mask = jnp.ones((n_episodes, n_agents), bool)
            emb = nets.agent_embeddings(agent.critic, agent.consts, state.obs, action, mask)
            state = jax.vmap(env.step)(state, agents_to_env_action(env.space, action, agent_index))
            return (state, alive * (1.0 - state.done)), (emb.p_w[:, 0], emb.gat[:, 0], alive)

        alive = jnp.ones(n_episodes)
        keys = jax.random.split(key_run, env.episode_length)
        return jax.lax.scan(step, (state, alive), keys)[1]

    p_w, gat, alive = jax.device_get(rollout(agent, key))  # [T, E, ...]
    keep = np.asarray(alive) > 0
    return {"p_w": np.asarray(p_w)[keep], "gat": np.asarray(gat)[keep]}


def tsne_2d(x: np.ndarray, seed: int = 0, perplexity: float = 30.0) -> np.ndarray:
    """t-SNE of ``x [N, d]`` to ``[N, 2]`` (scikit-learn's ``TSNE``, PCA initialisation);
    the perplexity is lowered to ``(N - 1) / 3`` when N is too small for it.

    Raises ImportError naming the ``paper`` extra when scikit-learn is missing.
    """
    try:
        from sklearn.manifold import TSNE
    except ImportError as e:
        raise ImportError(
            "t-SNE (Fig. 12) needs scikit-learn, the 'paper' extra: pip install -e '.[paper]' "
            "(or pip install 'scikit-learn>=1.5')"
        ) from e
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[0] < 4:
        raise ValueError(f"t-SNE needs points [N >= 4, d], got shape {x.shape}")
    perplexity = min(float(perplexity), (x.shape[0] - 1) / 3.0)
    return TSNE(2, perplexity=perplexity, init="pca", random_state=seed).fit_transform(x)


EMBEDDING_STAGES = {"p_w": "after p_w (e_i)", "gat": "after the GAT (e_i^(m))"}


def across_agents_share(x: np.ndarray) -> float:
    """Share of the spread of embeddings ``x [N, n_agents, d]`` that lies between the agents of
    one state: the mean over states of the variance across agents, over the total variance
    (both summed over the d features). 0 when every agent of a state has the same embedding,
    as after a GAT layer whose attention weights ``alpha_ij`` do not depend on the receiver i
    (GAT's static attention on a complete graph, Brody et al. 2022: whenever
    ``a^T [theta x_i || theta x_j]`` keeps its sign over j, LeakyReLU is linear there and the
    receiver's term cancels in the softmax); 1 when the state does not move them at all."""
    x = np.asarray(x, np.float64)
    total = float(x.reshape(-1, x.shape[-1]).var(axis=0).sum())
    if total == 0.0:
        return 0.0
    return float(x.var(axis=1).mean(axis=0).sum() / total)


def plot_agent_embeddings(
    embeddings: Mapping[str, Mapping[str, np.ndarray]],
    subspace_names: Sequence[str],
    path: str,
    title: str = "",
    seed: int = 0,
    perplexity: float = 30.0,
) -> None:
    """Fig. 12: one row per variant (``embeddings``: ``{label: collect_agent_embeddings(...)}``,
    e.g. ``{"AL+HN": ..., "SCORE": ...}``), one column per stage (after p_w, after the GAT);
    each panel is a t-SNE (``tsne_2d``, of that panel's N x n_agents points) coloured by
    sub-space (``subspace_names[i]`` for agent i), titled with ``across_agents_share``."""
    if not embeddings:
        raise ValueError("no embeddings to plot")
    names = list(subspace_names)
    fig = new_figure(4.0 * len(EMBEDDING_STAGES) + 1.8, 3.6 * len(embeddings))
    axes = fig.subplots(len(embeddings), len(EMBEDDING_STAGES), squeeze=False)
    for row, (label, emb) in zip(axes, embeddings.items(), strict=True):
        for ax, (stage, stage_title) in zip(row, EMBEDDING_STAGES.items(), strict=True):
            x = np.asarray(emb[stage])
            if x.ndim != 3 or x.shape[1] != len(names):
                raise ValueError(
                    f"{label!r} {stage}: expected [N, {len(names)} agents, d], got {x.shape}"
                )
            pts = tsne_2d(x.reshape(-1, x.shape[-1]), seed, perplexity).reshape(*x.shape[:2], 2)
            for colour, (i, name) in zip(_colours(len(names)), enumerate(names), strict=True):
                ax.scatter(pts[:, i, 0], pts[:, i, 1], s=8, alpha=0.6, color=colour, label=name)
            share = across_agents_share(x)
            ax.set_title(f"{label}: {stage_title}\n{share:.0%} of the spread across agents")
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0, -1].legend(
        fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), title="sub-action space"
    )
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=120)


# --- Figs. 6b/8b: fine-tuning on unseen sub-spaces ----------------------------------------------


def transfer_curves_from_compare(compare: dict) -> tuple[dict, dict]:
    """``(curves, initial)`` of the transfer rows of a ``compare_<env>.json``
    (``benchmarks/compare.py --transfer``): ``curves[label]`` its fine-tuning curves (a list of
    ``{"seed", "steps", "returns"}``), ``initial[label]`` its per-seed Initial returns."""
    rows = compare["rows"]
    curves = {k: v["converge"]["curves"] for k, v in rows.items() if "converge" in v}
    initial = {k: rows[k]["initial"]["per_seed"] for k in curves if "initial" in rows[k]}
    return curves, initial


# compare.py names a variant's row "<algorithm>-<variant>" and the plain one "<algorithm>".
TRANSFER_VARIANT_SUFFIXES = tuple(f"-{v}" for v in VARIANTS if v != "plain")
# Within a panel each variant keeps its colour, so the panels read alike.
_VARIANT_COLOURS = {"": "C0", **{s: f"C{i + 1}" for i, s in enumerate(TRANSFER_VARIANT_SUFFIXES)}}
_REFERENCE_ROW = "SCORE"


def transfer_panels(labels: Sequence[str]) -> list[tuple[str, list[str]]]:
    """Groups transfer rows into Fig. 6b/8b's panels: one per algorithm with its variants
    (``"PPO"``, ``"PPO-mask"``, ``"PPO-penalty"`` share the panel ``"PPO"``), in the order the
    algorithms first appear. SCORE's row, when there is one, is added to every other panel as
    the reference line; its own panel comes first, and is left out when SCORE would be alone in
    it while other panels show it. Returns ``[(panel title, [row labels])]``."""
    families: dict[str, list[str]] = {}
    for label in labels:
        family = label
        for suffix in TRANSFER_VARIANT_SUFFIXES:
            if label.endswith(suffix):
                family = label[: -len(suffix)]
        families.setdefault(family, []).append(label)
    reference = _REFERENCE_ROW if _REFERENCE_ROW in labels else None
    panels = []
    for family, rows in families.items():
        if reference is not None and reference not in rows:
            rows = [reference, *rows]
        panels.append((family, rows))
    panels.sort(key=lambda p: p[0] != reference)
    if len(panels) > 1 and panels[0][1] == [reference]:
        panels = panels[1:]
    return panels


def _row_colour(label: str, family: str) -> str:
    if label == _REFERENCE_ROW:
        return "black"
    return _VARIANT_COLOURS.get(label[len(family) :], "C3")


def plot_transfer_curves(
    curves: Mapping[str, Sequence[dict]],
    path: str,
    title: str = "",
    initial: Mapping[str, Sequence[float]] | None = None,
) -> None:
    """Figs. 6b/8b: deterministic evaluation return against fine-tuning decisions, one panel per
    algorithm with its transfer variants (``transfer_panels``; SCORE in black in every panel),
    every seed faint and the mean over seeds with its 95% band (``curves.plot_band``);
    ``curves[label]`` is a list of ``{"seed", "steps", "returns"}`` (compare.py's format) and
    ``initial[label]`` (the per-seed returns before fine-tuning) is drawn as a marker at
    decision 0 with its 95% interval. The panels share their axes."""
    if not curves:
        raise ValueError("no transfer curves to plot")
    panels = transfer_panels(list(curves))
    ncols = min(3, len(panels))
    nrows = -(-len(panels) // ncols)
    fig = new_figure(4.6 * ncols + 0.6, 3.4 * nrows + 0.6)
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False)
    for ax, (family, rows) in zip(axes.ravel(), panels, strict=False):
        span = max((max(c["steps"], default=0) for r in rows for c in curves[r]), default=0)
        for k, label in enumerate(rows):
            colour = _row_colour(label, family)
            data = {
                int(c["seed"]): (np.asarray(c["steps"], float), np.asarray(c["returns"], float))
                for c in curves[label]
                if len(c["steps"])
            }
            plot_band(ax, data, label, colour, band_label=None)
            if initial and label in initial:
                mean, lo, hi = t_interval(np.asarray(initial[label], float)[:, None])
                err = None if lo is None else [[mean[0] - lo[0]], [hi[0] - mean[0]]]
                # Side by side at decision 0, so the intervals do not hide one another.
                x = [-0.015 * k * span]
                ax.errorbar(x, mean, yerr=err, fmt="D", color=colour, ms=5, capsize=3)
        ax.set_title(family, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    for ax in axes.ravel()[len(panels) :]:
        ax.set_visible(False)
    for ax in axes[-1, :]:
        ax.set_xlabel("fine-tuning decisions")
    for ax in axes[:, 0]:
        ax.set_ylabel("episode return (deterministic)")
    fig.suptitle(
        (title or "fine-tuning on unseen sub-action spaces")
        + "\n(◆ before fine-tuning; mean of the seeds with its 95% band, each seed faint)",
        fontsize=10,
    )
    fig.savefig(path, dpi=120)
