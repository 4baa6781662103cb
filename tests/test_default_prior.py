"""The default-centred action prior (``TrainConfig.default_prior``) of every algorithm.

On a probe whose defaults are off-centre, an untrained deterministic policy plays the default
with the prior and mid-range without it (logit policies: the default choice is likely with the
prior, ~uniform without); a transfer run's new actors start at their defaults only with
``TransferSpec.new_actor_prior``. Nothing is trained: every check reads a fresh policy.
"""

import dataclasses

import jax
import numpy as np
import pytest

from envs.probe import ProbeEnv
from score_jax import registry
from score_jax.agents import growth
from score_jax.agents.base import BuildContext
from score_jax.agents.brax.config import SingleAgentConfig
from score_jax.agents.marl.config import MarlConfig
from score_jax.core.spaces import CompositeSpace, SubSpace
from score_jax.networks.actor import ActorConfig
from score_jax.networks.critic import CriticConfig
from score_jax.run.config import TrainConfig, TransferSpec, prior_agents, resolve
from score_jax.run.summary import resolved_config
from tests.tiny import TINY_SCORE

# defaults: a = 0.6 (normalised 0.6), b = -0.5, c = choice 3 of 0..4 (normalised 0.5); the
# mid-range action is 0 and c's middle choice is 2 (normalised 0)
SPACE = CompositeSpace(
    (
        SubSpace.continuous("a", 2, -1.0, 1.0, 0.6),
        SubSpace.continuous("b", 3, -1.0, 1.0, -0.5),
        SubSpace.discrete("c", 1, 0.0, 4.0, 3.0, n_choices=5),
    )
)
DEFAULT = np.asarray(SPACE.default_action())  # [3, 3]
ALGOS = ("score", "isac", "maddpg", "maac", "qmix", "sac", "ppo", "hppo")
LOGIT_POLICIES = ("score", "isac", "maddpg", "maac", "hppo")  # a categorical over c's choices


class OffCentreProbe(ProbeEnv):
    def __init__(self):
        super().__init__()
        self.space = SPACE


ENV = OffCentreProbe()
SETTINGS = {
    "score": dataclasses.replace(
        TINY_SCORE, critic=CriticConfig(hidden=32, agent_dim=32, asrl=False)
    ),
    "marl": MarlConfig(actor=ActorConfig(hidden=(32, 32)), critic_hidden=(32,), qmix_candidates=32),
    "single": SingleAgentConfig(hidden=(32, 32), head_hidden=16),
}


def build(algo: str, prior, agent_index=(0, 1, 2), trainable=None):
    ctx = BuildContext(
        env=ENV,
        agent_index=np.asarray(agent_index),
        width=SPACE.max_dim,
        prior=np.asarray(prior, bool),
        trainable=trainable,
        log=lambda *a: None,
    )
    entry = registry.entry(algo)
    return registry.builder(algo)(SETTINGS[entry.settings], ctx)


OBS = jax.random.uniform(jax.random.PRNGKey(7), (256, 4), minval=-1.0, maxval=1.0)


@pytest.mark.parametrize("algo", ALGOS)
def test_untrained_policy_starts_at_the_default_only_with_the_prior(algo):
    for prior in (True, False):
        algo_ = build(algo, np.full(3, prior))
        init, act = algo_.off_policy.init, algo_.off_policy.act
        state = init(jax.random.PRNGKey(0))
        det = np.asarray(act(state, OBS[:16], jax.random.PRNGKey(1), True))  # [16, 3, 3]
        a, b, c = det[:, 0, :2], det[:, 1, :3], det[:, 2, 0]
        c = np.round((c + 1.0) * 2.0) / 2.0 - 1.0  # the grid value the env plays (brax: flat)
        if prior:
            np.testing.assert_allclose(a, 0.6, atol=0.05, err_msg=algo)
            np.testing.assert_allclose(b, -0.5, atol=0.05, err_msg=algo)
            np.testing.assert_allclose(c, 0.5, atol=1e-5, err_msg=algo)
        elif algo == "qmix":  # a grid centred mid-range, which holds neither default
            assert np.all(np.abs(a - 0.6).max(-1) > 0.05) and np.all(np.abs(b + 0.5).max(-1) > 0.05)
        else:
            np.testing.assert_allclose(a, 0.0, atol=0.05, err_msg=algo)
            np.testing.assert_allclose(b, 0.0, atol=0.05, err_msg=algo)
            if algo in ("sac", "ppo"):  # the flat column at tanh(~0): c's middle choice
                np.testing.assert_allclose(c, 0.0, atol=0.05, err_msg=algo)
        if algo in LOGIT_POLICIES:  # the default choice's probability: ~0.83 vs ~0.2
            sampled = np.asarray(act(state, OBS, jax.random.PRNGKey(2), False))[:, 2, 0]
            share = float(np.mean(np.abs(sampled - 0.5) < 1e-3))
            assert (share > 0.65) if prior else (0.08 < share < 0.35), (algo, prior, share)


@pytest.mark.parametrize("algo", ("isac", "qmix"))  # SCORE's: tests/test_transfer.py
def test_grown_new_actors_start_at_the_default_only_when_asked(algo):
    source = build(algo, np.ones(2, bool), agent_index=(1, 2)).off_policy.init(
        jax.random.PRNGKey(0)
    )
    plan = growth.plan([1, 2], [0, 1, 2])  # a is new
    for new_prior in (False, True):
        grown_algo = build(algo, [new_prior, True, True], trainable=np.array([True, False, False]))
        init, act = grown_algo.off_policy.init, grown_algo.off_policy.act
        agent = grown_algo.grow(source, init(jax.random.PRNGKey(1)), plan, jax.random.PRNGKey(2))
        det = np.asarray(act(agent, OBS[:16], jax.random.PRNGKey(3), True))
        np.testing.assert_allclose(det[:, 1, :3], -0.5, atol=0.05)  # the old actor of b
        a = det[:, 0, :2]
        if new_prior:
            np.testing.assert_allclose(a, 0.6, atol=0.05, err_msg=algo)
        elif algo == "qmix":
            assert np.all(np.abs(a - 0.6).max(-1) > 0.05)
        else:
            np.testing.assert_allclose(a, 0.0, atol=0.05, err_msg=algo)


@pytest.mark.parametrize("algo", ("ppo", "hppo"))
def test_fixed_width_subset_run_starts_its_unseen_heads_untrained(algo):
    """The heads of sub-spaces a subset run does not control play the new sub-spaces' part
    after transfer (§4.3): they start mid-range, the controlled ones at their defaults."""
    algo_ = build(algo, np.ones(2, bool), agent_index=(1, 2))  # a unseen
    nets, (normalizer, policy, _) = algo_.networks, algo_.off_policy.init(jax.random.PRNGKey(0))
    flat = nets.parametric_action_distribution.mode(
        nets.policy_network.apply(normalizer, policy, OBS[:16])
    )
    action = np.asarray(SPACE.unflatten(flat))
    np.testing.assert_allclose(action[:, 0, :2], 0.0, atol=0.05)
    np.testing.assert_allclose(action[:, 1, :3], -0.5, atol=0.05)


def test_prior_agents_and_the_resolved_block():
    names = list(SPACE.names)
    new_a = TransferSpec("src", ("a",))
    on = lambda algo, transfer=None, **kw: prior_agents(
        TrainConfig(algo=algo, **kw), names, transfer
    ).tolist()
    assert on("score") == [True, True, True]
    assert on("qmix", default_prior=False) == [False, False, False]
    assert on("isac", new_a) == [False, True, True]  # new actors untrained by default (§4.3)
    assert on("isac", dataclasses.replace(new_a, new_actor_prior=True)) == [True, True, True]
    assert on("maac", dataclasses.replace(new_a, new_actor_prior=True), default_prior=False) == [
        True,
        False,
        False,
    ]
    # fixed width: the new sub-spaces' heads come from the subset run, untrained there
    assert on("ppo", new_a) == [False, True, True]
    # a spec saved before new_actor_prior existed gave new actors the prior
    old = {"source": "src", "new": ["a"], "finetune_old_actors": False}
    assert TransferSpec.from_dict(old).new_actor_prior
    assert not TransferSpec.from_dict(dataclasses.asdict(new_a)).new_actor_prior
    cfg = TrainConfig(env="probe", algo="score")
    spec = resolve(cfg, ENV)
    block = resolved_config(cfg, spec, ENV, np.arange(3), new_a)
    assert block["default_prior"] == ["b", "c"]
    off = dataclasses.replace(cfg, default_prior=False)
    assert resolved_config(off, spec, ENV, np.arange(3))["default_prior"] == []
