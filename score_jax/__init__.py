"""score-jax: SCORE (structured cooperative RL for time-varying composite action spaces) in JAX."""

__version__ = "0.1.0"
