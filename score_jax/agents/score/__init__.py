"""SCORE (§4, Alg. 1): ASRL-pretrained HVAE (``asrl``), hypernetwork GAT twin critic and
per-sub-space SAC actors (``networks``), transfer to unseen sub-spaces (``transfer``), and the
builder the registry calls (``algorithm``); settings in ``config``."""
