"""SCORE networks: the HVAE (§4.1), the masked GAT (§3.2), the graph critic (§4.2), the actors."""

from score_jax.networks.actor import (
    ActorConfig,
    ActorOutput,
    Actors,
    AgentActor,
    grow_agents,
    sample_actions,
    select_agents,
)
from score_jax.networks.critic import (
    FINETUNE_SUBTREES,
    CriticConfig,
    GraphCritic,
    TwinCritic,
    finetune_mask,
)
from score_jax.networks.gat import (
    GATWeights,
    flatten_gat_weights,
    gat_layer,
    gat_num_params,
    gat_shapes,
    gat_stack,
    init_gat_weights,
    unflatten_gat_weights,
)
from score_jax.networks.hvae import (
    HVAE,
    HVAEConfig,
    HVAEMetrics,
    ObservationSets,
    hvae_loss,
    init_hvae,
    make_hvae_train_step,
    make_optimizer,
    space_embeddings,
)
from score_jax.networks.mlp import MLP

__all__ = [
    "ActorConfig",
    "ActorOutput",
    "Actors",
    "AgentActor",
    "grow_agents",
    "sample_actions",
    "select_agents",
    "FINETUNE_SUBTREES",
    "CriticConfig",
    "GraphCritic",
    "TwinCritic",
    "finetune_mask",
    "GATWeights",
    "flatten_gat_weights",
    "gat_layer",
    "gat_num_params",
    "gat_shapes",
    "gat_stack",
    "init_gat_weights",
    "unflatten_gat_weights",
    "HVAE",
    "HVAEConfig",
    "HVAEMetrics",
    "ObservationSets",
    "hvae_loss",
    "init_hvae",
    "make_hvae_train_step",
    "make_optimizer",
    "space_embeddings",
    "MLP",
]
