"""Baselines of §5.1, each an ``algorithms.Algorithm`` driven by the shared off-policy trainer
(or the other engineers' on-policy drivers): they reuse the shared replay buffer, failure
masks, padding, evaluation, robustness sweep, checkpoints and transfer instead of copying
them. The multi-agent ones treat every sub-action space as an agent like SCORE does: ISAC
(independent SAC learners, ``isac``), MADDPG (centralised critic, deterministic actors,
``maddpg`` + the DDPG update in ``ddpg``), MAAC (attention critic, ``maac``)
and QMIX (discretised sub-spaces, monotonic mixer, ``qmix`` + ``qmix_candidates``); their
shared pieces are in ``marl_common`` and their sizes in ``marl_config.MarlConfig``
(``TrainConfig.marl``).
"""
