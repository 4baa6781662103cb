"""The robustness sweep: one compiled call equals a Python loop over the settings."""

import jax
import numpy as np

import envs
from score_jax.evaluation.robustness import MODES, make_sweep, plot_sweep, settings_grid, tabulate
from score_jax.run.episodes import evaluate


def _policy(env):
    return lambda state, key: (
        jax.vmap(env.best_action)(state.obs)
        + 0.05 * jax.random.normal(key, (state.obs.shape[0], 3, 3))
    )


def test_sweep_equals_python_loop_and_compiles_once(tmp_path):
    env = envs.make("probe", episode_length=6)
    act = _policy(env)
    agents = np.arange(3)
    settings = settings_grid(3, n_seeds=2)
    assert settings.n_failed.shape == (3 * 3 * 2,)
    traces = []
    inner = make_sweep(env, act, agents, episodes_per_setting=2)

    def counted(s, k):
        traces.append(1)
        return inner(s, k)

    sweep = jax.jit(counted)
    key = jax.random.PRNGKey(7)
    returns = sweep(settings, key)
    returns_again = sweep(
        settings_grid(3, n_seeds=2), jax.random.PRNGKey(8)
    )  # new values, same shapes
    assert len(traces) == 1 and returns.shape == (18, 2) and not np.allclose(returns, returns_again)

    single = jax.jit(lambda n, m, k: evaluate(env, act, k, 2, agents, n, m).returns)
    for i in range(settings.n_failed.shape[0]):
        k = jax.random.fold_in(key, settings.seed[i])
        np.testing.assert_allclose(
            returns[i], single(settings.n_failed[i], settings.mode[i], k), rtol=1e-5, atol=1e-5
        )

    table = tabulate(returns, settings, 3, 2)
    assert table.mean.shape == (3, 3) and table.modes == ["default", "random", "last"]
    # zero failures: every mode gives the plain evaluation; more failures cost reward here
    np.testing.assert_allclose(table.mean[0], table.mean[0, 0], rtol=1e-6)
    assert np.all(table.mean[2] < table.mean[0])
    plot_sweep(table, str(tmp_path / "sweep.png"))
    assert (tmp_path / "sweep.png").stat().st_size > 10_000
    assert "| 0 |" in table.markdown()


def test_count_zero_equals_plain_evaluation():
    env = envs.make("probe", episode_length=4)
    act = _policy(env)
    settings = settings_grid(3, n_seeds=1)
    returns = jax.jit(make_sweep(env, act, np.arange(3)))(settings, jax.random.PRNGKey(0))
    plain = evaluate(
        env, act, jax.random.fold_in(jax.random.PRNGKey(0), 0), 1, np.arange(3)
    ).returns
    for j in range(len(MODES)):
        np.testing.assert_allclose(
            returns[j * 1], plain, rtol=1e-6
        )  # settings (0 failed, mode j, seed 0)
