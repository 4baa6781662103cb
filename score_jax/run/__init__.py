"""The run layer: configuration and its resolution (``config``), building and restoring a run
(``build``), the jitted off-policy epoch (``trainer``), the drivers of in-process and
brax-driven training (``driver``, ``external``), what every run records (``recorder``,
``writers``, ``best_policy``), checkpoints (``checkpoint``), evaluation episodes and the
reference policies (``episodes``), and the data-parallel mesh (``sharding``)."""
