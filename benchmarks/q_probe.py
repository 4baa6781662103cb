"""Does a trained SCORE critic rank actions the way the environment does?

For a saved run (deterministic environment, e.g. the greenhouse) and each of its seeds:

1. play the run's deterministic policy for one episode and keep the state at every decision;
2. at a few decisions ``t``, take M candidate actions (the policy's own, the default, the
   planned references' actions where the environment has them, and uniformly random ones);
3. compute each candidate's TRUE action value ``Q^pi(s_t, a) = r(s_t, a) + sum_k gamma^k r_{t+k}``
   by stepping ``a`` and then following the deterministic policy to the end of the episode
   (rewards times the run's reward scale, the units the critic regresses on), and the critic's
   estimate ``min(Q_1, Q_2)(s_t, a)``;
4. report, per decision: Spearman's rank correlation between the two over the candidates, the
   spread (std over candidates) of each, the true and the estimated gain of the best candidate
   over the policy's action, and whether the candidate the critic ranks first is truly better
   than the policy's action.

A critic whose estimate is flat over actions (spread far below the true spread) or uncorrelated
with the true values gives the actors no direction; an actor that does not follow a critic that
does rank well shows as "critic's first choice truly better than the policy".

    python benchmarks/q_probe.py --run-dir runs/main-k6 [--policy last|best] [--candidates 64]
        [--decisions 0 5 10 15] [--out benchmarks/results]

Writes ``q_probe_<run name>.json`` and ``.md`` under ``--out`` (default ``runs/benchmarks``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


@dataclasses.dataclass
class Args:
    run_dir: str
    """A finished (or checkpointed) SCORE run."""
    policy: str = "last"
    """The policy that plays (``last`` or ``best``); its critic is the one saved with it."""
    candidates: int = 64
    """Uniformly random candidate actions per probed decision (plus policy, default, references)."""
    decisions: tuple[int, ...] = (0, 5, 10, 15)
    """Decisions (0-based, in the run's decision interval) at which actions are probed."""
    seed: int = 0
    """Key of the random candidates and of the episode's reset."""
    out: str = os.path.join(ROOT, "runs", "benchmarks")
    """Output folder (the committed ones: --out benchmarks/results)."""


def probe_seed(run, k: int, args: Args) -> dict:
    """The probe of seed ``k`` of ``run`` (see the module docstring)."""
    import jax
    import jax.numpy as jnp

    from score_jax.core.spaces import agents_to_env_action, sample_agent_actions
    from score_jax.run.episodes import reference_policies

    one = run.for_seed(k)
    agent, env, idx = one.state.agent, run.env, np.asarray(run.agent_index)
    space, width, nets = env.space, run.algo.off_policy.width, run.algo.networks
    gamma = float(run.algo.off_policy.hyper.gamma)
    scale = float(run.algo.off_policy.hyper.reward_scale)
    act = run.algo.policy(agent)
    T = int(env.episode_length)
    key = jax.random.PRNGKey(args.seed)
    refs = reference_policies(env, idx, width, planned=True)
    ref_names = [n for n in refs if n != "random"]

    def to_env(a):
        return agents_to_env_action(space, a, idx)

    def follow(state):
        """Discounted scaled return of following the policy from the batched ``state``."""

        def step(carry, _):
            s, ret, disc, alive = carry
            s = jax.vmap(env.step)(s, to_env(act(s, key)))
            ret = ret + alive * disc * s.reward * scale
            return (s, ret, disc * gamma, alive * (1.0 - s.done)), None

        b = state.obs.shape[0]
        carry = (state, jnp.zeros(b), jnp.full(b, gamma), 1.0 - state.done)
        (_, ret, _, _), _ = jax.lax.scan(step, carry, None, length=T)
        return ret

    @jax.jit
    def trajectory():
        s0 = jax.vmap(env.reset)(key[None])

        def step(s, _):
            a = act(s, key)
            return jax.vmap(env.step)(s, to_env(a)), (s, a)

        _, (states, actions) = jax.lax.scan(step, s0, None, length=T)
        return states, actions

    @jax.jit
    def values(state1, cands):
        """``state1`` batch of one, ``cands [M, n_agents, w]`` -> (true, critic) ``[M]``."""
        m = cands.shape[0]
        s = jax.tree.map(lambda x: jnp.broadcast_to(x, (m, *x.shape[1:])), state1)
        s1 = jax.vmap(env.step)(s, to_env(cands))
        true_q = s1.reward * scale + (1.0 - s1.done) * follow(s1)
        mask = jnp.ones((m, cands.shape[1]), bool)
        q = nets.q_fn(agent.critic, agent.consts, s.obs, cands, mask)
        return true_q, jnp.min(q, axis=-1)

    states, actions = trajectory()
    rows = []
    for t in args.decisions:
        if t >= T:
            continue
        st = jax.tree.map(lambda x, t=t: x[t], states)
        named = {"policy": actions[t][0]}
        for name in ref_names:
            named[name] = refs[name](st, key)[0]
        rand = sample_agent_actions(
            space, idx, jax.random.fold_in(key, t), (args.candidates,), width
        )
        cands = jnp.concatenate([jnp.stack(list(named.values())), rand])
        true_q, est_q = (np.asarray(x) for x in values(st, cands))
        from scipy.stats import spearmanr

        rho = float(spearmanr(true_q, est_q).statistic)
        names = list(named) + [f"random {i}" for i in range(args.candidates)]
        first = int(np.argmax(est_q))
        best = int(np.argmax(true_q))
        rows.append(
            {
                "decision": int(t),
                "spearman": rho,
                "true_std": float(np.std(true_q)),
                "critic_std": float(np.std(est_q)),
                "true": {n: float(true_q[i]) for i, n in enumerate(names[: len(named)])},
                "critic": {n: float(est_q[i]) for i, n in enumerate(names[: len(named)])},
                "truly_best": names[best],
                "true_gain_of_best": float(true_q[best] - true_q[0]),
                "critic_gain_of_best": float(est_q[best] - est_q[0]),
                "critic_first": names[first],
                "critic_first_truly_better": bool(true_q[first] > true_q[0]),
            }
        )
    return {"seed": int(run.seeds[k]), "decisions": rows}


def markdown(result: dict) -> str:
    lines = [
        f"# Q probe of `{result['run_dir']}` ({result['policy']} policy)",
        "",
        "Per probed decision: Spearman's rho between the critic's min(Q1, Q2) and the true action "
        f"value over {result['candidates']} random candidates plus the policy's, the default and "
        "the references' actions; spreads are stds over the candidates (reward-scaled units); "
        "gains are of the truly best candidate over the policy's action.",
        "",
        "| seed | decision | rho | true std | critic std | true gain | critic gain | "
        "critic's first | truly better than policy |",
        "|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for s in result["seeds"]:
        for r in s["decisions"]:
            lines.append(
                f"| {s['seed']} | {r['decision']} | {r['spearman']:.2f} | {r['true_std']:.4f} | "
                f"{r['critic_std']:.4f} | {r['true_gain_of_best']:.4f} | "
                f"{r['critic_gain_of_best']:.4f} | {r['critic_first']} | "
                f"{'yes' if r['critic_first_truly_better'] else 'no'} |"
            )
    return "\n".join(lines) + "\n"


def main(args: Args) -> dict:
    from score_jax.run.build import restore_run

    run = restore_run(args.run_dir, log=lambda m: print(m, flush=True), policy=args.policy)
    if run.algo.name != "score":
        raise SystemExit(f"error: q_probe reads a SCORE critic; {args.run_dir} is {run.algo.name}")
    seeds = [probe_seed(run, k, args) for k in range(run.num_seeds)]
    result = {
        "run_dir": args.run_dir,
        "policy": args.policy,
        "candidates": args.candidates,
        "seeds": seeds,
    }
    out = args.out
    os.makedirs(out, exist_ok=True)
    name = os.path.basename(os.path.normpath(args.run_dir))
    with open(os.path.join(out, f"q_probe_{name}.json"), "w") as f:
        json.dump(result, f, indent=1)
    text = markdown(result)
    with open(os.path.join(out, f"q_probe_{name}.md"), "w") as f:
        f.write(text)
    print(text)
    return result


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))
