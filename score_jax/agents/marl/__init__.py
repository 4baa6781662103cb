"""The multi-agent baselines of §5.1, on the shared off-policy trainer, replay buffer, failure
masks, evaluation, robustness sweep, checkpoints and transfer: ISAC (independent SAC learners,
``isac``), MADDPG (centralised critic, deterministic actors, ``maddpg`` + the DDPG update in
``ddpg``), MAAC (attention critic, ``maac``) and QMIX (discretised sub-spaces, monotonic
mixer, ``qmix`` + ``qmix_candidates``). Shared pieces in ``common``, settings in ``config``
(``--marl.*``). Every sub-action space is an agent, as in SCORE."""
