"""The agents layer: every algorithm's networks, losses and update, built from
``score_jax.networks`` and the bottom layer, never from the run layer above.

- ``base``: the interfaces (``Algorithm``, ``OffPolicyAlgorithm``, ``BuildContext``,
  ``AgentConsts``); ``replay``: the transition type and ring buffer; ``growth``: growing the
  agent axis for transfer (§4.3), shared by every algorithm that can grow;
- ``sac``: the multi-agent SAC losses and update shared by SCORE, ISAC and MAAC;
- ``score``: SCORE (ASRL, networks, its transfer); ``marl``: ISAC, MADDPG, MAAC, QMIX;
  ``brax``: brax's SAC / PPO and H-PPO, with the flat-action view of an environment.
"""
