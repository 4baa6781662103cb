"""Multi-agent soft actor-critic shared by SCORE, ISAC and MAAC: settings (``config``), state
types (``state``), losses (``losses``) and the one-jit update (``update``)."""
