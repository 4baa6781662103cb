"""Transfer a trained run to unseen sub-action spaces (§4.3) and fine-tune it: a thin wrapper of
``score-transfer`` (``score_jax.cli.transfer``).

    python train.py --env greenhouse --subspaces co2,lighting --run-dir runs/gh-subset
    python transfer.py --checkpoint runs/gh-subset --total-steps 60000 [--compare-scratch]
"""

import sys

from score_jax.cli.transfer import cli

if __name__ == "__main__":
    sys.exit(cli())
