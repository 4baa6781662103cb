"""One module class, ``n`` independent copies: parameters stacked on a leading axis.

Every per-agent network (SCORE's actors, the twin critics, the baselines' per-agent critics and
Q networks) is this ``nn.vmap``; stacking makes growing the agent axis for transfer (§4.3) a
concatenation, and one batched matmul serves all copies.
"""

from __future__ import annotations

import flax.linen as nn


def stacked(module_cls: type[nn.Module], axis_size: int, in_axes=None) -> type[nn.Module]:
    """``module_cls`` vmapped over a leading parameter axis of ``axis_size`` copies.

    ``in_axes=None``: every copy sees the same inputs (actors on the shared observation);
    ``in_axes=0``: copy ``i`` sees row ``i`` of the inputs. Outputs are stacked on axis 0.
    """
    return nn.vmap(
        module_cls,
        variable_axes={"params": 0},
        split_rngs={"params": True},
        in_axes=in_axes,
        out_axes=0,
        axis_size=axis_size,
    )
