"""Robustness sweep (§5.2.3, §5.3.3, Figs. 7/9) in ONE jit-compiled call.

For a trained policy: full evaluation episodes for every (number of failed sub-spaces
0..n-1) x (failure mode default / random / last) x seed, with the failed sub-spaces redrawn
at random every step. The settings are a flat batch of arrays and ``evaluate`` is vmapped
over them, so the whole grid is one XLA program.

    score-robustness --run-dir runs/greenhouse-score-s0      (score_jax.cli.robustness)
"""

from __future__ import annotations

import dataclasses
import os
import time

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from score_jax.agents.base import ActFn
from score_jax.core.failures import FailureMode
from score_jax.evaluation.stats import aggregate_one, format_interval
from score_jax.run import distributed
from score_jax.run.checkpoint import dump_json
from score_jax.run.episodes import evaluate
from score_jax.run.sharding import make_data_mesh

MODES = (FailureMode.DEFAULT, FailureMode.RANDOM, FailureMode.LAST)


@struct.dataclass
class SweepSettings:
    """A flat batch of S evaluation settings: ``[S]`` arrays."""

    n_failed: jax.Array
    mode: jax.Array
    seed: jax.Array


def settings_grid(n_agents: int, n_seeds: int, modes=MODES) -> SweepSettings:
    """Every (n_failed in 0..n_agents-1) x mode x seed, flattened in that order."""
    f, m, s = np.meshgrid(
        np.arange(n_agents), np.asarray([int(x) for x in modes]), np.arange(n_seeds), indexing="ij"
    )
    return SweepSettings(
        jnp.asarray(f.ravel(), jnp.int32),
        jnp.asarray(m.ravel(), jnp.int32),
        jnp.asarray(s.ravel(), jnp.int32),
    )


def make_sweep(env, act_fn: ActFn, agent_index, episodes_per_setting: int = 1):
    """``sweep(settings, base_key) -> returns [S, episodes_per_setting]`` — jit it once.

    Each setting evaluates with key ``fold_in(base_key, seed)``: the same seed gives the same
    initial states for every count and mode, so the curves differ only by the failures.
    """

    def one(n_failed, mode, seed, base_key):
        key = jax.random.fold_in(base_key, seed)
        return evaluate(env, act_fn, key, episodes_per_setting, agent_index, n_failed, mode).returns

    def sweep(settings: SweepSettings, base_key):
        return jax.vmap(one, in_axes=(0, 0, 0, None))(
            settings.n_failed, settings.mode, settings.seed, base_key
        )

    return sweep


def shard_settings(settings: SweepSettings, devices=None) -> SweepSettings:
    """Spread the settings axis over all devices (a ``data`` mesh), so the one-call sweep uses
    every device: on a CPU split into one XLA host device per core
    (``XLA_FLAGS=--xla_force_host_platform_device_count=N``), every core. XLA partitions the
    vmapped program along that axis; settings stay on one device when S is not a multiple of
    the device count or there is only one device."""
    devices = jax.devices() if devices is None else devices
    if len(devices) < 2 or settings.n_failed.shape[0] % len(devices):
        return settings
    return jax.device_put(
        settings,
        jax.sharding.NamedSharding(make_data_mesh(devices), jax.sharding.PartitionSpec("data")),
    )


def on_devices_of(settings: SweepSettings, tree):
    """``tree`` with every array held on fewer devices than the (sharded) settings replicated
    over the settings' mesh: a run restored onto one device (a checkpoint, brax's agents) is
    swept with settings spread over every device. Unchanged when the settings are not spread."""
    sharding = settings.n_failed.sharding
    if not isinstance(sharding, jax.sharding.NamedSharding) or len(sharding.device_set) < 2:
        return tree
    replicated = jax.sharding.NamedSharding(sharding.mesh, jax.sharding.PartitionSpec())
    n = len(sharding.device_set)
    spread = lambda x: len(getattr(x, "sharding", replicated).device_set) == n
    return jax.tree.map(lambda x: x if spread(x) else jax.device_put(x, replicated), tree)


@dataclasses.dataclass
class SweepTable:
    """Statistics per (n_failed, mode) over seeds (and episodes)."""

    n_failed: list[int]
    modes: list[str]
    mean: np.ndarray  # [counts, modes]
    std: np.ndarray
    min: np.ndarray
    max: np.ndarray
    returns: np.ndarray  # [counts, modes, seeds * episodes]

    def to_dict(self) -> dict:
        out = {"n_failed": self.n_failed, "modes": self.modes}
        for name in ("mean", "std", "min", "max", "returns"):
            out[name] = np.asarray(getattr(self, name)).tolist()
        return out

    def markdown(self) -> str:
        head = "| failed | " + " | ".join(f"{m} mean ± std" for m in self.modes) + " |"
        sep = "|---|" + "---|" * len(self.modes)
        rows = [
            f"| {c} | "
            + " | ".join(
                f"{self.mean[i, j]:.1f} ± {self.std[i, j]:.1f}" for j in range(len(self.modes))
            )
            + " |"
            for i, c in enumerate(self.n_failed)
        ]
        return "\n".join([head, sep, *rows])


def tabulate(
    returns: np.ndarray, settings: SweepSettings, n_agents: int, n_seeds: int, modes=MODES
) -> SweepTable:
    """``returns [S, E]`` of one policy, or ``[K, S, E]`` of K trained seeds (pooled: every cell
    holds the K x n_seeds x E episodes)."""
    r = np.asarray(returns)
    r = r[None] if r.ndim == 2 else r
    k, e = r.shape[0], r.shape[-1]
    r = r.reshape(k, n_agents, len(modes), n_seeds * e).transpose(1, 2, 0, 3)
    r = r.reshape(n_agents, len(modes), k * n_seeds * e)
    return SweepTable(
        list(range(n_agents)),
        [m.name.lower() for m in modes],
        r.mean(-1),
        r.std(-1),
        r.min(-1),
        r.max(-1),
        r,
    )


def iqm_over_seeds(per_seed: np.ndarray, modes: list[str], seed: int = 0) -> dict:
    """IQM over trained seeds with its 95% stratified-bootstrap interval, per cell:
    ``per_seed [K, n_failed, modes]`` (each trained seed's mean return in the cell) ->
    ``{"iqm": [[{value, lo, hi}] per mode] per failed count, "markdown": table}``."""
    k, n, m = per_seed.shape
    cells = [
        [aggregate_one(f"{i}/{modes[j]}", per_seed[:, i, j], seed=seed).iqm for j in range(m)]
        for i in range(n)
    ]
    head = "| failed | " + " | ".join(f"{mode} IQM [95% CI]" for mode in modes) + " |"
    lines = [head, "|---|" + "---|" * m]
    lines += [
        f"| {i} | " + " | ".join(format_interval(c.value, c.lo, c.hi) for c in row) + " |"
        for i, row in enumerate(cells)
    ]
    iqm = [[{"value": c.value, "lo": c.lo, "hi": c.hi} for c in row] for row in cells]
    return {"iqm": iqm, "markdown": "\n".join(lines), "trained_seeds": k}


def plot_sweep(table: SweepTable, path: str, title: str = "") -> None:
    """Figs. 7/9 style: dot = mean, thick bar = std, thin bar = min..max, one colour per mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"default": "black", "random": "tab:blue", "last": "tab:red"}
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.asarray(table.n_failed, float)
    for j, mode in enumerate(table.modes):
        xs = x + (j - 1) * 0.18
        c = colours.get(mode, None)
        ax.vlines(xs, table.min[:, j], table.max[:, j], color=c, lw=1)
        ax.vlines(
            xs,
            table.mean[:, j] - table.std[:, j],
            table.mean[:, j] + table.std[:, j],
            color=c,
            lw=4,
        )
        ax.plot(xs, table.mean[:, j], "o", color=c, label=mode)
    ax.set_xticks(x)
    ax.set_xlabel("failed sub-action spaces (redrawn every step)")
    ax.set_ylabel("episode return")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(title="failure mode")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_sweep(run, n_seeds: int = 10, log=print) -> SweepTable:
    """Sweep every seed of a trained run (see ``run.build.restore_run``) in one call; write JSON
    (pooled table, and each trained seed's mean per cell) + PNG into its directory. Distributed:
    every process sweeps its own seeds (the settings are not spread then); process 0 writes."""
    log = distributed.primary_only(log)
    n = len(run.agent_index)
    settings = settings_grid(n, n_seeds)
    if not distributed.multiprocess():
        settings = shard_settings(settings)
    # The agent's state is an argument, not a constant of the program: XLA would otherwise
    # constant-fold the networks into the executable (slow compiles, one per policy).
    one = lambda agent, settings, key: make_sweep(run.env, run.algo.policy(agent), run.agent_index)(
        settings, key
    )
    sweep = jax.jit(jax.vmap(one, in_axes=(0, None, 0)) if run.batched else one)
    agent = on_devices_of(settings, run.state.agent)
    t0 = time.time()
    returns = distributed.to_host(
        jax.block_until_ready(sweep(agent, settings, run.eval_keys(30_000)))
    )
    seconds = time.time() - t0
    table = tabulate(returns, settings, n, n_seeds)
    per_seed = returns.reshape(-1, n, len(MODES), n_seeds * returns.shape[-1]).mean(-1)
    if not distributed.is_primary():
        return table
    over = iqm_over_seeds(per_seed, table.modes, run.config.seed) if run.num_seeds > 1 else None
    dump_json(
        os.path.join(run.run_dir, "robustness.json"),
        {
            **table.to_dict(),
            "n_seeds": n_seeds,
            "trained_seeds": list(run.seeds),
            "per_trained_seed_mean": per_seed.tolist(),
            **({"iqm_over_trained_seeds": over["iqm"]} if over else {}),
            "seconds": seconds,
        },
    )
    plot_sweep(
        table,
        os.path.join(run.run_dir, "robustness.png"),
        f"{run.config.algo} on {run.config.env}: robustness"
        + (f" ({run.num_seeds} trained seeds pooled)" if run.num_seeds > 1 else ""),
    )
    log(
        f"robustness sweep: {run.num_seeds} trained seed(s) x {settings.n_failed.shape[0]} "
        f"settings x 1 episode in one call, {seconds:.1f} s (incl. compile)"
    )
    log(table.markdown())
    if over:
        log(f"over the {run.num_seeds} trained seeds (each seed's mean per cell):")
        log(over["markdown"])
    return table
