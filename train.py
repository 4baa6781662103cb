"""Train SCORE (or a baseline): a thin wrapper of ``score-train`` (``score_jax.cli.train``).

python train.py                                  # SCORE on the greenhouse, laptop-sized defaults
python train.py --env spider --total-steps 200000
python train.py --resume runs/greenhouse-score-s0
python train.py --help                           # every option
"""

import sys

from score_jax.cli.train import cli

if __name__ == "__main__":
    sys.exit(cli())
