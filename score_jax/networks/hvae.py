"""The hierarchical VAE of the action space representation learning stage (§4.1, Fig. 3, eq. 2).

Modules (all share the per-observation state encoder ``e_o = q_phi(o)``, which the critic
reuses, §4.2):

  q_phi(c | O_i)        space encoder: encode every element of the observation set O_i of
                        sub-space i, masked mean-pool, Gaussian head -> c_i.
  q_psi(z | o, a, c)    action encoder: the projection of sub-action a (in observation o) into
                        the common latent action space.
  p_u(o' | z, c)        decoder of the observation that followed the sub-action.
  p_s([o']_t | z, c)    LSTM predictor of the next t observations (self-supervised auxiliary).
  p(z | c)              small learned conditional prior; p(c) = N(0, I).

Choices the paper leaves open (documented here once):

* Set elements are transitions ``(o_prev, a, o)``. With uniformly random composite actions
  every observation has the same marginal distribution whichever sub-space was varied, so a
  mean-pool of observations alone cannot tell sub-spaces apart; pairing each observation with
  the sub-action that produced it (and its dim mask) can.
* The action encoder sees the observation the sub-action was taken in (as the critic does:
  ``e_a = q_psi(o^t, a^t, c)``) and the decoder reconstructs the observation that followed;
  any q gives a valid ELBO, and this makes z describe the sub-action's effect instead of
  copying o.
* ``action_recon_weight`` (default 1) adds log p(a | z, c) over the sub-action's valid dims,
  a Gaussian with the FIXED std ``action_recon_std``: z must then pin the sub-action down to
  about that precision even where the sub-action barely moves the observation (the critic
  sees actions only through z; with a learned std the ELBO is indifferent to encoding a
  uniform sub-action and z collapses, e.g. on the probe env). Set it to 0 for eq. 2 exactly.
* Training splits every set into context and target fixings (half of the k groups each, a
  fresh random split per step): c ~ q_phi(c | context), the element terms are computed on
  the targets. Any q is a valid variational distribution, so this is still the ELBO of eq. 2
  (on the targets); it stops c from memorising the set's own samples (the j elements of a
  fixing share a start state), so c describes the sub-space, not the sample. Embeddings
  (``space_embeddings``) use the whole set.
* ``code_contrast_weight`` (default 0 = eq. 2's terms only, and nothing of the term is
  computed, so the default program is the one the study log measured) adds an InfoNCE term over
  the S sets of a batch: the code of a set's context half must pick out the same set's target half
  among all S target halves by distance (``code_contrast``). Eq. 2 rewards c only as far as
  the decoders need it; sub-spaces of equal width whose effects differ little at first (the
  greenhouse's temperature and CO2 hours) then get codes close together, and a critic that
  conditions on c sees nearly the same agent twice.
* Observation likelihoods are Gaussian with a learned per-dimension log-std (global
  parameters), so every term is in nats and the ELBO is a proper bound.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from score_jax.networks.mlp import MLP, gaussian_head, soft_clip


@dataclasses.dataclass(frozen=True)
class HVAEConfig:
    """HVAE sizes and training settings (§4.1).

    Attributes:
      obs_embed_dim: width of the state embedding e_o = q_phi(o).
      space_embed_dim: width of the sub-space embedding c.
      latent_dim: width of the latent sub-action z.
      hidden: hidden width of every MLP and of the LSTM.
      predict_steps: t, the number of future observations the LSTM predicts.
      kl_weight: beta on both KL terms (1 = the ELBO of eq. 2).
      action_recon_weight: weight of log p(a | z, c) (see the module docstring; 0 = eq. 2).
      action_recon_std: fixed std of p(a | z, c), in normalised action units.
      code_contrast_weight: weight of the InfoNCE term that separates the codes of different
        sub-spaces (see the module docstring; 0 = off).
      code_contrast_temperature: tau of that term's logits ``-||c_i - c_j||^2 / tau``.
      learning_rate: Adam step size.
      min_log_std: lower bound of every log-std (likelihoods and posteriors).
    """

    obs_embed_dim: int = 32
    space_embed_dim: int = 16
    latent_dim: int = 16
    hidden: int = 64
    predict_steps: int = 4
    kl_weight: float = 1.0
    action_recon_weight: float = 1.0
    action_recon_std: float = 0.1
    code_contrast_weight: float = 0.0
    code_contrast_temperature: float = 1.0
    learning_rate: float = 1e-3
    min_log_std: float = -5.0


@struct.dataclass
class ObservationSets:
    """Observation sets O_i of S sub-spaces, m = k * j transitions each (§4.1).

    Attributes:
      obs: ``[S, m, obs_size]`` observation after applying the composite action.
      prev_obs: ``[S, m, obs_size]`` observation the action was applied in.
      actions: ``[S, m, width]`` the sub-action a_{i,j}^k of the set's sub-space (padded 0).
      dim_mask: ``[S, width]`` bool, the sub-space's real columns.
      future: ``[S, m, t, obs_size]`` the next t observations (same composite action kept).
      future_mask: ``[S, m, t]`` bool, False after the episode ended.
      set_mask: ``[S, m]`` bool, False on padding elements.
      group: ``[S, m]`` int32, the fixing k (0..k-1) each element was collected under.
    """

    obs: jax.Array
    prev_obs: jax.Array
    actions: jax.Array
    dim_mask: jax.Array
    future: jax.Array
    future_mask: jax.Array
    set_mask: jax.Array
    group: jax.Array


def observation_set_shapes(
    obs_size: int, n_sets: int, k: int, j: int, t: int, width: int
) -> ObservationSets:
    """The shapes and dtypes of the ``ObservationSets`` that ASRL collects for ``n_sets``
    sub-spaces with ``k`` fixings of ``j`` sub-actions and ``t`` future steps (no environment
    traced: restoring a run needs the HVAE's shapes, not its data)."""
    m = k * j
    f32 = lambda *shape: jax.ShapeDtypeStruct(shape, jnp.float32)
    flag = lambda *shape: jax.ShapeDtypeStruct(shape, jnp.bool_)
    return ObservationSets(
        obs=f32(n_sets, m, obs_size),
        prev_obs=f32(n_sets, m, obs_size),
        actions=f32(n_sets, m, width),
        dim_mask=flag(n_sets, width),
        future=f32(n_sets, m, t, obs_size),
        future_mask=flag(n_sets, m, t),
        set_mask=flag(n_sets, m),
        group=jax.ShapeDtypeStruct((n_sets, m), jnp.int32),
    )


@struct.dataclass
class HVAEMetrics:
    """Per-observation terms of eq. 2 in nats (averaged over sets; all ``[]``).

    ``elbo = -(recon + pred + kl_z) - kl_c`` (kl_c already divided by the set size): eq. 2's
    ELBO, without the action-reconstruction term ``act`` (the negative log-likelihood of the
    sub-action under its decoder, not part of eq. 2; logged on its own) and without the code
    contrast ``contrast`` (InfoNCE cross-entropy in nats, ``code_contrast``; 0 when its weight
    is 0, as it is then not computed). ``loss`` is the minimised objective (with ``kl_weight``,
    ``action_recon_weight * act`` and ``code_contrast_weight * contrast``).
    """

    loss: jax.Array
    elbo: jax.Array
    recon: jax.Array
    pred: jax.Array
    act: jax.Array
    kl_z: jax.Array
    kl_c: jax.Array
    contrast: jax.Array


def gaussian_nll(x: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Elementwise -log N(x; mean, exp(log_std)^2)."""
    return (
        0.5 * jnp.square((x - mean) * jnp.exp(-log_std)) + log_std + 0.5 * math.log(2.0 * math.pi)
    )


def gaussian_kl(mean_q, log_std_q, mean_p, log_std_p) -> jax.Array:
    """KL(N(mean_q, std_q^2) || N(mean_p, std_p^2)) summed over the last axis."""
    var_ratio = jnp.exp(2.0 * (log_std_q - log_std_p))
    mahalanobis = jnp.square((mean_q - mean_p) * jnp.exp(-log_std_p))
    return 0.5 * jnp.sum(var_ratio + mahalanobis - 1.0, axis=-1) - jnp.sum(
        log_std_q - log_std_p, axis=-1
    )


class LikelihoodScales(nn.Module):
    """Learned per-dimension log-stds of the reconstruction and prediction likelihoods."""

    obs_size: int

    @nn.compact
    def __call__(self) -> tuple[jax.Array, jax.Array]:
        zeros = nn.initializers.zeros
        return self.param("obs_log_std", zeros, (self.obs_size,)), self.param(
            "pred_log_std", zeros, (self.obs_size,)
        )


class HVAE(nn.Module):
    """The HVAE of Fig. 3. Every method works on one sample (leading batch axes allowed).

    Use a method with ``model.apply({"params": p}, ..., method=HVAE.encode_obs)``;
    ``model.init(key, <one set>, key)`` (``__call__``) creates every parameter.
    """

    config: HVAEConfig
    obs_size: int
    action_width: int

    def setup(self):
        cfg = self.config
        h = cfg.hidden
        self.obs_encoder = MLP((h,), cfg.obs_embed_dim)  # q_phi per observation (e_o)
        self.set_element = MLP((h,), h)  # per-transition features, mean-pooled
        self.space_head = MLP((h,), 2 * cfg.space_embed_dim)  # -> q_phi(c | O_i)
        self.action_encoder = MLP((h, h), 2 * cfg.latent_dim)  # q_psi(z | o, a, c)
        self.decoder = MLP((h, h), self.obs_size)  # p_u(o' | z, c)
        self.action_decoder = MLP((h,), self.action_width)  # p(a | z, c)
        self.prior = MLP((h,), 2 * cfg.latent_dim)  # p(z | c)
        self.predictor_init = nn.Dense(2 * h)  # (z, c) -> initial LSTM carry
        self.predictor = nn.RNN(nn.OptimizedLSTMCell(h))  # p_s
        self.predictor_out = nn.Dense(self.obs_size)
        self.scales = LikelihoodScales(self.obs_size)  # a submodule: created only where used

    # --- encoders -------------------------------------------------------------------------
    def encode_obs(self, obs: jax.Array) -> jax.Array:
        """q_phi state encoder: ``[..., obs_size] -> e_o [..., obs_embed_dim]``."""
        return self.obs_encoder(obs)

    def encode_space(
        self,
        obs_set: jax.Array,
        set_mask: jax.Array,
        prev_obs_set: jax.Array,
        action_set: jax.Array,
        dim_mask: jax.Array,
    ) -> tuple[jax.Array, jax.Array]:
        """q_phi(c | O_i): ``(mean [c], log_std [c])`` of one sub-space's set.

        Args:
          obs_set: ``[m, obs_size]`` observations after the sub-actions.
          set_mask: ``[m]`` bool, False on padding elements (excluded from the mean-pool).
          prev_obs_set: ``[m, obs_size]`` observations the sub-actions were taken in.
          action_set: ``[m, width]`` the sub-actions (padded columns ignored).
          dim_mask: ``[width]`` bool, the sub-space's real columns.
        """
        m = obs_set.shape[0]
        mask_f = jnp.broadcast_to(dim_mask.astype(jnp.float32), (m, self.action_width))
        feats = jnp.concatenate(
            [self.encode_obs(prev_obs_set), self.encode_obs(obs_set), action_set * mask_f, mask_f],
            -1,
        )
        feats = nn.relu(self.set_element(feats))
        w = set_mask.astype(jnp.float32)[:, None]
        pooled = jnp.sum(feats * w, 0) / jnp.maximum(jnp.sum(w), 1.0)
        return gaussian_head(self.space_head(pooled), self.config.min_log_std, 2.0)

    def encode_action(
        self, obs: jax.Array, action: jax.Array, dim_mask: jax.Array, c: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """q_psi(z | o, a, c): ``obs [..., obs_size], action [..., width], dim_mask [..., width],
        c [..., c_dim] -> (mean [..., z], log_std [..., z])``. Padded columns are zeroed here,
        and the dim mask is an input, so sub-spaces of different widths stay distinguishable."""
        mask_f = jnp.asarray(dim_mask, jnp.float32)
        e_o = self.encode_obs(obs)
        # The concatenation [e_o, a, mask, c] as parts: e_o (per sample) and mask, c (per agent)
        # enter the first layer once each instead of once per (sample, agent) pair.
        return gaussian_head(
            self.action_encoder((e_o, action * mask_f, mask_f, c)), self.config.min_log_std, 2.0
        )

    # --- decoders and priors --------------------------------------------------------------
    def decode(self, z: jax.Array, c: jax.Array) -> jax.Array:
        """p_u(o | z, c) mean: ``z [..., z_dim], c [..., c_dim] -> [..., obs_size]``."""
        return self.decoder(_cat(z, c))

    def decode_action(self, z: jax.Array, c: jax.Array) -> jax.Array:
        """p(a | z, c) mean: ``-> [..., width]`` (only valid columns enter the loss)."""
        return self.action_decoder(_cat(z, c))

    def predict(self, z: jax.Array, c: jax.Array) -> jax.Array:
        """p_s([o]_t | z, c) mean: ``-> [..., t, obs_size]``, an LSTM fed (z, c) at every step."""
        x = _cat(z, c)
        carry_c, carry_h = jnp.split(jnp.tanh(self.predictor_init(x)), 2, axis=-1)
        t = self.config.predict_steps
        inputs = jnp.broadcast_to(x[..., None, :], (*x.shape[:-1], t, x.shape[-1]))
        hidden = self.predictor(inputs, initial_carry=(carry_c, carry_h))
        return self.predictor_out(hidden)

    def prior_z(self, c: jax.Array) -> tuple[jax.Array, jax.Array]:
        """p(z | c): ``c [..., c_dim] -> (mean, log_std) [..., z_dim]``."""
        return gaussian_head(self.prior(c), self.config.min_log_std, 2.0)

    def log_stds(self) -> tuple[jax.Array, jax.Array]:
        """Learned observation likelihood log-stds ``(recon [obs_size], pred [obs_size])``."""
        lo = self.config.min_log_std
        obs_log_std, pred_log_std = self.scales()
        return soft_clip(obs_log_std, lo, 2.0), soft_clip(pred_log_std, lo, 2.0)

    # --- the per-set negative ELBO ---------------------------------------------------------
    def __call__(
        self, obs, prev_obs, actions, dim_mask, future, future_mask, context_mask, target_mask, key
    ) -> dict:
        """Terms of eq. 2 for ONE set (shapes of ``ObservationSets`` without the S axis).

        ``c`` is sampled from q_phi(c | elements where ``context_mask``); the per-element
        terms are returned for every element (``hvae_loss`` keeps those in ``target_mask``).
        Returns ``recon, pred, act, kl_z`` (``[m]``) and ``kl_c`` (``[]``), all in nats, and,
        when ``code_contrast_weight > 0``, the posterior means of c from the context and from
        the target elements (``c_context``, ``c_target``, ``[c_dim]``; for ``code_contrast``).
        """
        key_c, key_z = jax.random.split(key)
        mean_c, log_std_c = self.encode_space(obs, context_mask, prev_obs, actions, dim_mask)
        c = mean_c + jnp.exp(log_std_c) * jax.random.normal(key_c, mean_c.shape)
        kl_c = gaussian_kl(mean_c, log_std_c, jnp.zeros_like(mean_c), jnp.zeros_like(log_std_c))

        m = obs.shape[0]
        c_m = jnp.broadcast_to(c, (m, c.shape[-1]))
        mean_z, log_std_z = self.encode_action(prev_obs, actions, dim_mask, c_m)
        z = mean_z + jnp.exp(log_std_z) * jax.random.normal(key_z, mean_z.shape)
        prior_mean, prior_log_std = self.prior_z(c_m)
        kl_z = gaussian_kl(mean_z, log_std_z, prior_mean, prior_log_std)

        obs_ls, pred_ls = self.log_stds()
        act_ls = jnp.full((self.action_width,), math.log(self.config.action_recon_std))
        recon = jnp.sum(gaussian_nll(obs, self.decode(z, c_m), obs_ls), -1)
        pred = jnp.sum(gaussian_nll(future, self.predict(z, c_m), pred_ls), -1)  # [m, t]
        pred = jnp.sum(jnp.where(future_mask, pred, 0.0), -1)
        act = jnp.sum(
            jnp.where(dim_mask, gaussian_nll(actions, self.decode_action(z, c_m), act_ls), 0.0), -1
        )
        terms = {"recon": recon, "pred": pred, "act": act, "kl_z": kl_z, "kl_c": kl_c}
        if self.config.code_contrast_weight > 0:  # static: off adds nothing to the program
            terms["c_context"] = mean_c
            terms["c_target"] = self.encode_space(obs, target_mask, prev_obs, actions, dim_mask)[0]
        return terms


def _cat(z: jax.Array, c: jax.Array) -> jax.Array:
    batch = jnp.broadcast_shapes(z.shape[:-1], c.shape[:-1])
    return jnp.concatenate(
        [jnp.broadcast_to(z, (*batch, z.shape[-1])), jnp.broadcast_to(c, (*batch, c.shape[-1]))], -1
    )


def split_context_target(sets: ObservationSets, key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Random split of every set's fixings into halves: ``(context [S, m], target [S, m])`` bool.

    A set with a single fixing is used whole as both context and target.
    """
    S, m = sets.set_mask.shape

    def one(group, valid, key):
        n_groups = jnp.max(jnp.where(valid, group, -1)) + 1
        u = jnp.where(jnp.arange(m) < n_groups, jax.random.uniform(key, (m,)), 2.0)
        rank = jnp.argsort(jnp.argsort(u))  # a random order of the real groups 0..n_groups-1
        context = rank[group] < n_groups // 2
        whole = n_groups < 2
        return valid & (context | whole), valid & (~context | whole)

    return jax.vmap(one)(sets.group, sets.set_mask, jax.random.split(key, S))


def code_contrast(c_context: jax.Array, c_target: jax.Array, temperature: float) -> jax.Array:
    """Symmetric InfoNCE over S sets: ``c_context, c_target [S, c_dim] -> []`` nats.

    With logits ``l_ij = -||c_context_i - c_target_j||^2 / temperature``, the mean of the
    cross-entropies of matching row i to column i and column j to row j: 0 when every set's
    halves are far closer to each other than to any other set's, ``log S`` when all codes
    coincide (0 for S = 1: nothing to separate).
    """
    d2 = jnp.sum(jnp.square(c_context[:, None, :] - c_target[None, :, :]), -1)
    logits = -d2 / temperature
    rows = -jnp.diagonal(jax.nn.log_softmax(logits, axis=1))
    cols = -jnp.diagonal(jax.nn.log_softmax(logits, axis=0))
    return 0.5 * (jnp.mean(rows) + jnp.mean(cols))


def _element_args(sets: ObservationSets) -> tuple:
    return (sets.obs, sets.prev_obs, sets.actions, sets.dim_mask, sets.future, sets.future_mask)


def init_hvae(model: HVAE, key: jax.Array, sets: ObservationSets) -> dict:
    """Parameters of ``model`` (the ``"params"`` collection), shaped by one set of ``sets``."""
    key_init, key_sample = jax.random.split(key)
    one = jax.tree_util.tree_map(lambda x: x[0], sets)
    return model.init(key_init, *_element_args(one), one.set_mask, one.set_mask, key_sample)[
        "params"
    ]


def hvae_loss(
    params: dict, model: HVAE, sets: ObservationSets, key: jax.Array
) -> tuple[jax.Array, HVAEMetrics]:
    """Negative ELBO of eq. 2 per observation, averaged over the S sets.

    Per set, with c ~ q_phi(c | context half) and the targets T (``split_context_target``):
    ``[sum_{o in T} (recon + pred + w_a act + beta kl_z) + beta kl_c] / |T|`` -- eq. 2 with
    its per-set KL(q_phi || p(c)) counted once per set, divided by the set size so the scale
    does not depend on m. One reparameterised sample of c per set and of z per element. Plus
    ``code_contrast_weight`` times ``code_contrast`` of the halves' codes (once per batch).
    """
    cfg = model.config
    key_split, key_sample = jax.random.split(key)
    context, target = split_context_target(sets, key_split)
    terms = jax.vmap(lambda *a: model.apply({"params": params}, *a))(
        *_element_args(sets), context, target, jax.random.split(key_sample, sets.set_mask.shape[0])
    )
    contrast = jnp.zeros(())
    if cfg.code_contrast_weight > 0:
        contrast = code_contrast(
            terms.pop("c_context"), terms.pop("c_target"), cfg.code_contrast_temperature
        )
    w = target.astype(jnp.float32)
    count = jnp.maximum(jnp.sum(w, -1), 1.0)  # [S]
    per_set = {k: jnp.sum(v * w, -1) / count for k, v in terms.items() if k != "kl_c"}
    kl_c = terms["kl_c"] / count
    loss_s = (
        per_set["recon"]
        + per_set["pred"]
        + cfg.action_recon_weight * per_set["act"]
        + cfg.kl_weight * (per_set["kl_z"] + kl_c)
    )
    elbo_s = -(per_set["recon"] + per_set["pred"] + per_set["kl_z"] + kl_c)  # eq. 2 alone
    loss = jnp.mean(loss_s)
    if cfg.code_contrast_weight > 0:
        loss = loss + cfg.code_contrast_weight * contrast
    metrics = HVAEMetrics(
        loss=loss,
        elbo=jnp.mean(elbo_s),
        recon=jnp.mean(per_set["recon"]),
        pred=jnp.mean(per_set["pred"]),
        act=jnp.mean(per_set["act"]),
        kl_z=jnp.mean(per_set["kl_z"]),
        kl_c=jnp.mean(kl_c),
        contrast=contrast,
    )
    return metrics.loss, metrics


def make_optimizer(config: HVAEConfig) -> optax.GradientTransformation:
    """Adam with global-norm clipping (the learned log-stds make early gradients large)."""
    return optax.chain(optax.clip_by_global_norm(10.0), optax.adam(config.learning_rate))


def hvae_train_step(model: HVAE, optimizer: optax.GradientTransformation) -> Callable:
    """``step(params, opt_state, sets, key) -> (params, opt_state, HVAEMetrics)`` (pure: jit it,
    or vmap it over seeds). Each step draws a fresh context/target split of every set; the
    metrics are those of the step's batch, before the update.
    """

    def step(params, opt_state, sets: ObservationSets, key):
        grads, metrics = jax.grad(hvae_loss, has_aux=True)(params, model, sets, key)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, metrics

    return step


def make_hvae_train_step(model: HVAE, optimizer: optax.GradientTransformation) -> Callable:
    """ONE jitted ``hvae_train_step``."""
    return jax.jit(hvae_train_step(model, optimizer))


def space_embeddings(model: HVAE, params: dict, sets: ObservationSets) -> jax.Array:
    """Posterior means of q_phi(c | O_i) over the whole sets: ``[S, c_dim]``."""

    def one(obs, set_mask, prev_obs, actions, dim_mask):
        return model.apply(
            {"params": params}, obs, set_mask, prev_obs, actions, dim_mask, method=HVAE.encode_space
        )[0]

    return jax.vmap(one)(sets.obs, sets.set_mask, sets.prev_obs, sets.actions, sets.dim_mask)
