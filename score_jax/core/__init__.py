"""The bottom layer: composite action spaces, masks and failure modes, and the lazy registry
helper. Nothing here imports another project module, so every other layer (``envs``,
``score_jax.networks``, the agents, the run and evaluation layers) may import it."""
