"""Prediction (docs/method.md, "Inference") and the paper's baselines behind one interface.

:func:`predict` is pure and ``jax.jit``-compiled once per (method, n, R, bank size, image
batch shape). For every method it

1. encodes F once per image with the EBM (and once with the DMO for ``method="dmo"``);
2. scores the whole bank of training motions in chunks of ``chunk`` (memory stays bounded
   for any bank size) and keeps the ``n`` lowest-energy motions;
3. optimises those n candidates with the chosen method (:data:`METHODS`);
4. scores every optimised candidate with the EBM (reusing its F; the starts keep their step-2
   energies) and returns them and the starts ranked (lowest energy first), so execution can
   fall back to the next candidate.

:func:`top_candidates` (step 2) and :func:`refine` (steps 3-4) are the two halves, for
comparing several methods from one scoring of the bank; the :class:`Ranking` passed between them
carries F and the starts' energies, so neither is computed twice.

Methods (all start from the same top-n; settings of docs/method.md):

* ``sort``      EBM ranking only, no optimisation;
* ``dmo``       the Deep Motion Optimizer applied R times, vmapped over the candidates,
  reusing F; every intermediate step is a candidate;
* ``langevin``  x <- x - eps * dE/dx + sqrt(2 eps) * noise, eps = 1e-3, 100 iterations;
* ``gd``        the same without noise;
* ``vaebm-l``   Langevin in the motion VAE's latent space on E(decode(z)) + |z|^2 / 2, step 1e-2;
* ``vaebm-s``   the same with step 1e-3;
* ``dfo``       IBC's derivative-free optimiser (resample by softmax(-E), perturb, shrink).

Gradient methods update uv, z, the 6-D rotation and grasp (never time) and project at the
end: uv to [-1, 1], grasp to [0, 1], rotation re-orthonormalised (Gram–Schmidt).
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from envs.motion import (GRASP, NUM_STEPS, POSE_DIM, ROT6D, TIME, UV, count_non_finite, describe_array,
                         matrix_to_rot6d, rot6d_to_matrix)

from .checks import check_arrays, check_params, is_concrete, is_integer
from .config import CoarseRanking, Preset, get_preset
from .losses import dmo_unroll
from .networks import DMONet, EBMNet
from .selection import PHASES, selection_scores
from .vae import VAENet


@dataclasses.dataclass(frozen=True)
class OptimizerSettings:
    """Baseline settings (docs/method.md, "Baselines"); the defaults are the paper's."""

    langevin_step: float = 1e-3
    langevin_iters: int = 100
    vaebm_l_step: float = 1e-2
    vaebm_s_step: float = 1e-3
    vaebm_iters: int = 100
    dfo_iters: int = 3
    dfo_noise: float = 0.02  # initial std of the perturbation, in motion units
    dfo_shrink: float = 0.5


class Models(NamedTuple):
    """Parameters of one task's trained networks (``dmo`` / ``vae`` may be None when the
    method does not need them)."""

    ebm: Any
    dmo: Any = None
    vae: Any = None
    selection: Any = None  # the DMO's selection head, weights [PHASES * w + 1] (dmo_jax.selection); None: by energy


class Ranking(NamedTuple):
    """What :func:`top_candidates` hands to :func:`refine`: per image, the ``n`` lowest-energy bank
    ``motions [..., n, 101, 11]`` (best first), their ``energies [..., n]`` and the EBM's
    ``feature`` F ``[..., H, W, C]``, so that refining neither re-encodes the image nor re-scores
    the starts. ``feature`` may be None (F is then recomputed): a caller that keeps many rankings
    can drop it to save memory (256² paper preset: 64 MB per image)."""

    motions: jax.Array
    energies: jax.Array
    feature: jax.Array | None = None

    def first(self, n: int) -> "Ranking":
        """The best ``n`` of each image's motions (the same F)."""
        return Ranking(self.motions[..., :n, :, :], self.energies[..., :n], self.feature)


class BankCache(NamedTuple):
    """A bank of ``motions [N, 101, 11]`` with their ``pose`` activations ``[N, 101, P]`` under one
    EBM (:func:`cache_bank`): the head's work on the poses alone, which does not depend on the
    image, done once for every image the bank is scored for. Valid only with the EBM parameters
    it was made with. :func:`predict` and :func:`top_candidates` take it in place of the bank;
    the energies equal the bank's to float rounding."""

    motions: jax.Array
    pose: jax.Array


class Prediction(NamedTuple):
    """``motion [..., 101, 11]`` the best candidate; ``candidates [..., K, 101, 11]`` all
    candidates, best first, and their ``energies [..., K]``: ranked by energy (ascending) unless
    the networks have a selection head (:attr:`Models.selection`, ``dmo`` only), which ranks them
    by its score instead. K = n * (R + 1) for ``dmo``,
    n for ``sort``, 2 n for the other methods (originals + optimised)."""

    motion: jax.Array
    candidates: jax.Array
    energies: jax.Array


def check_request(preset: Preset, method: str, image_shape, bank_shape, n: int, R: int,
                  coarse: CoarseRanking | None = None) -> None:
    """Static checks of a :func:`predict` call (``image_shape`` None: no image); raises ``ValueError``
    naming what is wrong."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if image_shape is not None:
        s = preset.image_size
        if len(image_shape) not in (3, 4) or tuple(image_shape[-3:]) != (s, s, 4):
            raise ValueError(f"image must be [{s}, {s}, 4] or [B, {s}, {s}, 4] for preset {preset.name!r}, "
                             f"got {tuple(image_shape)}")
        if len(image_shape) == 4 and image_shape[0] < 1:
            raise ValueError(f"the image batch is empty (shape {tuple(image_shape)}); expected at least one image")
    if len(bank_shape) != 3 or tuple(bank_shape[1:]) != (NUM_STEPS, POSE_DIM):
        raise ValueError(f"bank must be [N, {NUM_STEPS}, {POSE_DIM}] motions, got {tuple(bank_shape)}")
    if bank_shape[0] < 1:
        raise ValueError("the bank of motions is empty")
    if not 1 <= n <= bank_shape[0]:
        raise ValueError(f"n must be in [1, bank size {bank_shape[0]}], got {n}")
    if R < 0:
        raise ValueError(f"R must be >= 0, got {R}")
    if coarse is not None:
        if not isinstance(coarse, CoarseRanking) or not all(is_integer(v) for v in coarse):
            raise ValueError(f"coarse must be a CoarseRanking(stride, keep) of integers, None or 'preset', "
                             f"got {coarse!r}")
        if not 1 <= coarse.stride < NUM_STEPS:
            raise ValueError(f"coarse.stride must be in [1, {NUM_STEPS - 1}], got {coarse.stride}")
        if not n <= coarse.keep <= bank_shape[0]:
            raise ValueError(f"coarse.keep must be in [n = {n}, bank size {bank_shape[0]}], got {coarse.keep}")


# --------------------------------------------------------------------------- helpers
_OPTIMISED = jnp.ones((POSE_DIM,), bool).at[TIME].set(False)


def project_motions(motions: jax.Array) -> jax.Array:
    """uv to [-1, 1], grasp to [0, 1], rotation re-orthonormalised; time untouched."""
    rot = matrix_to_rot6d(rot6d_to_matrix(motions[..., ROT6D]))
    return (motions.at[..., UV].set(jnp.clip(motions[..., UV], -1.0, 1.0))
            .at[..., ROT6D].set(rot)
            .at[..., GRASP].set(jnp.clip(motions[..., GRASP], 0.0, 1.0)))


def default_chunk() -> int:
    """Bank motions scored at once per image when a call does not say: 32 on a CPU, where the
    head's activations (32 x 101 tokens; the attention weights 32 x 4 x 101 x 101) then stay in
    the caches (bank of 1,000 on 2 cores: 0.48 s at 32, 0.67 s at 256; BENCHMARKS.md), and 256
    on an accelerator, whose throughput needs larger products."""
    return 32 if jax.default_backend() == "cpu" else 256


def _in_chunks(x, chunk: int):
    """``x [N, ...] -> [ceil(N / chunk), chunk, ...]``, the last chunk padded with zeros."""
    padded = jnp.concatenate([x, jnp.zeros(((-x.shape[0]) % chunk,) + x.shape[1:], x.dtype)])
    return padded.reshape((-1, chunk) + x.shape[1:])


def chunked_energy(ebm: EBMNet, params, feature, motions, chunk: int, pose=None) -> jax.Array:
    """Energies of ``motions [N, T, 11]`` under one image's ``F``, ``chunk`` at a time (``pose``:
    their :meth:`~dmo_jax.networks.EBMNet.pose_activations` ``[N, T, P]``, or None)."""
    n = motions.shape[0]
    if n <= chunk:
        return ebm.energy(params, feature, motions, pose=pose)
    energies = jax.lax.map(lambda mp: ebm.energy(params, feature, mp[0], pose=mp[1]),
                           (_in_chunks(motions, chunk), None if pose is None else _in_chunks(pose, chunk)))
    return energies.reshape(-1)[:n]


@functools.partial(jax.jit, static_argnames=("preset", "chunk"))
def _pose_activations_jit(params, motions, *, preset, chunk):
    ebm = EBMNet(preset)
    pose = jax.lax.map(lambda m: ebm.pose_activations(params, m), _in_chunks(motions, chunk))
    return pose.reshape((-1,) + pose.shape[2:])[:motions.shape[0]]


def cache_bank(models: Models, bank: jax.Array, *, preset: Preset, chunk: int | None = None) -> BankCache:
    """The :class:`BankCache` of ``bank [N, 101, 11]`` under ``models.ebm``: compute once, pass to
    :func:`predict` / :func:`top_candidates` for every image (``bin/evaluate`` does, per task).
    Raises ``ValueError`` for the arguments :func:`predict` checks."""
    preset, _, bank, _, chunk, _ = _checked_call(models, preset, "sort", None, bank, None, 1, 0, chunk)
    if isinstance(bank, BankCache):
        return bank
    return BankCache(bank, _pose_activations_jit(models.ebm, jnp.asarray(bank), preset=preset, chunk=chunk))


def langevin(energy_fn, x0, key, step: float, iters: int, noise: bool = True):
    """``iters`` steps of x <- x - step * grad + sqrt(2 step) * eta (eta = 0 without noise);
    ``energy_fn`` maps ``x`` to per-candidate energies."""
    grad_fn = jax.grad(lambda x: jnp.sum(energy_fn(x)))

    def body(x, k):
        x = x - step * grad_fn(x)
        if noise:
            x = x + jnp.sqrt(2.0 * step) * jax.random.normal(k, x.shape, x.dtype)
        return x, None

    x, _ = jax.lax.scan(body, x0, jax.random.split(key, iters))
    return x


def _masked(delta):
    """Zero the update of the time channel."""
    return jnp.where(_OPTIMISED, delta, 0.0)


# --------------------------------------------------------------------------- one image
def bank_top_n(ebm: EBMNet, params, feature, bank, n: int, chunk: int,
               coarse: CoarseRanking | None) -> tuple[jax.Array, jax.Array]:
    """Indices ``int32 [n]`` of the ``n`` lowest-energy motions of ``bank`` (motions or their
    :class:`BankCache`) under one image's ``feature`` F, best first, and their energies ``[n]``."""
    motions, pose = (bank.motions, bank.pose) if isinstance(bank, BankCache) else (bank, None)
    kept = None
    if coarse is not None:
        every = slice(None, None, coarse.stride)
        rough = chunked_energy(ebm, params, feature, motions[:, every], chunk, None if pose is None else pose[:, every])
        kept = jax.lax.top_k(-rough, coarse.keep)[1]
        motions, pose = motions[kept], None if pose is None else pose[kept]
    neg_energy, top = jax.lax.top_k(-chunked_energy(ebm, params, feature, motions, chunk, pose), n)
    return (top if kept is None else kept[top]), -neg_energy


def _top_n(preset: Preset, n: int, chunk: int, coarse: CoarseRanking | None, models: Models, image,
           bank) -> Ranking:
    """The ``n`` lowest-energy motions of ``bank`` for one image (best first), with F."""
    ebm = EBMNet(preset)
    feature = ebm.encode(models.ebm, image)
    top, energies = bank_top_n(ebm, models.ebm, feature, bank, n, chunk, coarse)
    return Ranking((bank.motions if isinstance(bank, BankCache) else bank)[top], energies, feature)


class _Call(NamedTuple):
    """What an optimiser of :data:`METHOD_REGISTRY` works with, for one image."""

    preset: Preset
    models: Models
    image: jax.Array  # [S, S, 4]
    energy: Callable[[jax.Array], jax.Array]  # motions [K, 101, 11] -> energies [K] under the image's F
    R: int
    settings: OptimizerSettings


def _sort(call: _Call, start, key):
    return start[:0]


def _dmo(call: _Call, start, key):
    dmo = DMONet(call.preset)
    f_dmo = dmo.encode(call.models.dmo, call.image)
    refined = dmo_unroll(dmo, call.models.dmo, f_dmo, start, call.R) if call.R > 0 else jnp.zeros((0,) + start.shape)
    return refined.reshape((-1,) + start.shape[1:])


def _gradient(call: _Call, start, key, noise: bool):
    # time is never changed: its gradient is masked out before each update
    masked_energy = lambda x: call.energy(start + _masked(x - start))
    x = langevin(masked_energy, start, key, call.settings.langevin_step, call.settings.langevin_iters, noise)
    return project_motions(start + _masked(x - start))


def _vaebm(call: _Call, start, key, step: float):
    vae = VAENet(call.preset.vae)
    z0, _ = vae.encode(call.models.vae, start)
    time = start[..., TIME]
    decode = lambda z: vae.decode(call.models.vae, z).at[..., TIME].set(time)
    z = langevin(lambda z: call.energy(decode(z)) + 0.5 * jnp.sum(z**2, axis=-1), z0, key, step,
                 call.settings.vaebm_iters, True)
    return project_motions(decode(z))


def _dfo(call: _Call, start, key):
    x, sigma = start, call.settings.dfo_noise
    for k in jax.random.split(key, call.settings.dfo_iters):
        k_pick, k_noise = jax.random.split(k)
        pick = jax.random.categorical(k_pick, -call.energy(x), shape=(start.shape[0],))
        x = project_motions(x[pick] + _masked(sigma * jax.random.normal(k_noise, x.shape)))
        sigma *= call.settings.dfo_shrink
    return x


class Method(NamedTuple):
    """A way to optimise the EBM's top n: ``optimise(call, start [n, 101, 11], key)`` returns the
    new candidates; ``needs``: the networks it uses besides the EBM (fields of :class:`Models`);
    ``uses_R``: whether R (the DMO's refinements) changes its result; ``candidates(n, R)``: K,
    how many ranked candidates :func:`predict` returns (starts included); ``selected``: whether
    its candidates are ranked by the selection head where the networks have one
    (:attr:`Models.selection`), else by energy."""

    optimise: Callable
    needs: tuple[str, ...] = ()
    uses_R: bool = False
    candidates: Callable[[int, int], int] = lambda n, R: 2 * n
    selected: bool = False


#: The methods of :func:`predict` (docs/method.md, "Baselines"), by name.
METHOD_REGISTRY: dict[str, Method] = {
    "sort": Method(_sort, candidates=lambda n, R: n),
    "dmo": Method(_dmo, ("dmo",), True, lambda n, R: n * (R + 1), selected=True),
    "langevin": Method(functools.partial(_gradient, noise=True)),
    "gd": Method(functools.partial(_gradient, noise=False)),
    "vaebm-l": Method(lambda call, start, key: _vaebm(call, start, key, call.settings.vaebm_l_step), ("vae",)),
    "vaebm-s": Method(lambda call, start, key: _vaebm(call, start, key, call.settings.vaebm_s_step), ("vae",)),
    "dfo": Method(_dfo),
}
METHODS = tuple(METHOD_REGISTRY)
#: Methods whose result depends on R (the DMO's refinements); the others ignore it.
METHODS_USING_R = tuple(name for name, m in METHOD_REGISTRY.items() if m.uses_R)
_NETWORK_NAMES = {"dmo": "DMO", "vae": "motion VAE"}


def num_candidates(method: str, n: int, R: int) -> int:
    """K, the number of ranked candidates :func:`predict` returns."""
    return METHOD_REGISTRY[method].candidates(n, R)


def _refine_one(preset: Preset, method: str, R: int, chunk: int, settings: OptimizerSettings, models: Models,
                image, ranking: Ranking, key) -> Prediction:
    """Optimise one image's starting motions ``ranking.motions [n, 101, 11]`` with ``method`` and
    rank the starts and the results by energy, or by the selection head (a ranking's missing F or
    energies are computed)."""
    ebm = EBMNet(preset)
    start = ranking.motions
    f_ebm = ebm.encode(models.ebm, image) if ranking.feature is None else ranking.feature
    energy = lambda m: ebm.energy(models.ebm, f_ebm, m)
    start_energy = energy(start) if ranking.energies is None else ranking.energies
    new = METHOD_REGISTRY[method].optimise(_Call(preset, models, image, energy, R, settings), start, key)

    # the starts keep their bank-scoring energies: only the optimised motions are scored here
    cands = jnp.concatenate([start, new])
    if models.selection is not None and METHOD_REGISTRY[method].selected:
        # one pass gives the head's input and the new energies
        pooled, phases = ebm.pooled_and_phases(models.ebm, f_ebm, cands, PHASES)
        energies = jnp.concatenate([start_energy, ebm.energy_of_pooled(models.ebm, pooled[start.shape[0]:])])
        order = jnp.argsort(-selection_scores(models.selection, phases, energies))
    else:
        energies = jnp.concatenate([start_energy, chunked_energy(ebm, models.ebm, f_ebm, new, chunk)]) \
            if new.shape[0] else start_energy
        order = jnp.argsort(energies)
    cands, energies = cands[order], energies[order]
    return Prediction(cands[0], cands, energies)


def image_devices(batch: int) -> int:
    """How many local devices a batch of ``batch`` images is split over: the most that split it
    evenly. On a CPU whose cores are exposed as devices (``envs.platform.expose_cpu_cores_as_devices``)
    each core then scores its own images, where one program runs most of its small ops on one
    thread; on one accelerator, 1."""
    devices = len(jax.local_devices())
    return max(k for k in range(1, min(devices, batch) + 1) if batch % k == 0)


def map_over_images(one: Callable, devices: int, replicated: tuple, images):
    """``one(*replicated, image)`` for each of ``images [B, ...]``, one image after another, with the
    images split along B over the first ``devices`` local devices (``replicated`` given whole to
    each); the results are joined along B. Each device runs the program one device would run on
    its part, so the results are the same."""
    def mapped(*args):
        return jax.lax.map(lambda image: one(*args[:-1], image), args[-1])

    if devices == 1:
        return mapped(*replicated, images)
    mesh = jax.sharding.Mesh(np.asarray(jax.local_devices()[:devices]), ("images",))
    P = jax.sharding.PartitionSpec
    return jax.shard_map(mapped, mesh=mesh, in_specs=(P(),) * len(replicated) + (P("images"),),
                         out_specs=P("images"))(*replicated, images)


@functools.partial(jax.jit, static_argnames=("preset", "n", "chunk", "coarse", "devices"))
def _top_candidates_jit(models, image, bank, *, preset, n, chunk, coarse, devices=1):
    one = functools.partial(_top_n, preset, n, chunk, coarse)
    if image.ndim == 3:
        return one(models, image, bank)
    # A batch is scored one image after another: vmapped, B images would hold B chunks of the
    # head's activations at once (10 images x 256 motions of the ViT variant's 357-token
    # attention: 17 GB resident in bin/evaluate).
    return map_over_images(lambda m, b, x: one(m, x, b), devices, (models, bank), image)


@functools.partial(jax.jit, static_argnames=("preset", "method", "R", "chunk", "settings"))
def _refine_jit(models, image, ranking, key, *, preset, method, R, chunk, settings):
    one = functools.partial(_refine_one, preset, method, R, chunk, settings, models)
    if image.ndim == 3:
        return one(image, ranking, key)
    return jax.vmap(one)(image, ranking, jax.random.split(key, image.shape[0]))


@functools.partial(jax.jit, static_argnames=("preset", "method", "n", "R", "chunk", "settings", "coarse", "devices"))
def _predict_jit(models, image, bank, key, *, preset, method, n, R, chunk, settings, coarse, devices=1):
    ranking = _top_candidates_jit(models, image, bank, preset=preset, n=n, chunk=chunk, coarse=coarse,
                                  devices=devices)
    return _refine_jit(models, image, ranking, key, preset=preset, method=method, R=R, chunk=chunk, settings=settings)


def predict(models: Models, image: jax.Array, bank: jax.Array, key: jax.Array, *, preset: Preset,
            method: str = "dmo", n: int = 8, R: int = 1, chunk: int | None = None,
            settings: OptimizerSettings = OptimizerSettings(),
            coarse: CoarseRanking | None | str = "preset") -> Prediction:
    """Predict motions for ``image`` with the trained networks of one task.

    Args:
      models: :class:`Models` (EBM parameters; DMO parameters for ``dmo``; VAE parameters
        for ``vaebm-l`` / ``vaebm-s``).
      image: ``[S, S, 4]`` float32 network image (``dmo_jax.data.network_image``) or a
        batch ``[B, S, S, 4]`` (every output gains a leading B axis; the bank is scored one
        image after another, the candidates are optimised vmapped over the images).
      bank: ``[N, 101, 11]`` training motions to score, or their :class:`BankCache`
        (:func:`cache_bank`; less work per image, the same energies to float rounding).
      key: PRNG key (used by the stochastic methods).
      preset: the networks' :class:`~dmo_jax.config.Preset` (or its name).
      method: one of :data:`METHODS`.
      n: candidates kept from the bank (1 <= n <= N).
      R: DMO refinements (``dmo`` only; R = 0 returns the EBM's ranking).
      chunk: bank motions scored at once per image (bounds memory); None: :func:`default_chunk`.
      settings: the baselines' step sizes and iteration counts.
      coarse: a :class:`~dmo_jax.config.CoarseRanking` scores the bank in two stages (less
        work; it may miss motions the full scoring would keep); None: every motion on all its
        poses; ``"preset"`` (default): the preset's ``coarse`` where it keeps more than n and
        fewer than N motions (the ``cpu`` preset: stride 6, keep 64), else every motion.

    Returns:
      :class:`Prediction` — best motion, ranked candidates, energies.

    Raises:
      ValueError: one line saying what is wrong and what was expected — unknown method or
        preset, image not ``[S, S, 4]`` / ``[B, S, S, 4]`` floating-point in [0, 1], bank not
        ``[N, 101, 11]`` floating-point, NaN or inf in image or bank, n outside [1, N],
        R < 0, a coarse ranking keeping fewer than n or more than N, a key that is not one
        PRNG key, parameters missing or of another preset or variant, an empty image batch; and non-finite energies or motions in the result
        (NaN or inf parameters, or motions so large the networks overflow; the check reads
        the result on the host, 0.02 ms for 10 images on 2 CPU cores). Inside the caller's
        ``jax.jit`` the arrays are tracers: shapes and dtypes are still checked, values (NaN,
        range, the result) are not.
    """
    preset, image, bank, key, chunk, coarse = _checked_call(models, preset, method, image, bank, key, n, R, chunk,
                                                            coarse=coarse)
    return _finite(_predict_jit(models, image, bank, key, preset=preset, method=method, n=n,
                                R=R if method in METHODS_USING_R else 0, chunk=chunk, settings=settings,
                                coarse=coarse, devices=_devices_for(image)))


def top_candidates(models: Models, image: jax.Array, bank: jax.Array, *, preset: Preset, n: int = 8,
                   chunk: int | None = None, coarse: CoarseRanking | None | str = "preset") -> Ranking:
    """Step 2 of :func:`predict` alone: a :class:`Ranking` of the ``n`` lowest-energy bank motions
    per image (``motions [n, 101, 11]``, or ``[B, n, 101, 11]`` for a batch of images, best
    first), with their energies and the EBM's F.

    With :func:`refine` it splits :func:`predict` in two, so that several methods can start
    from one scoring of the bank (the costly part: N EBM evaluations per image).
    ``refine(models, image, top_candidates(models, image, bank, ...), key, ...)`` equals
    ``predict(models, image, bank, key, ...)``. ``coarse`` as in :func:`predict`. Raises
    ``ValueError`` as :func:`predict` does.
    """
    preset, image, bank, _, chunk, coarse = _checked_call(models, preset, "sort", image, bank, None, n, 0, chunk,
                                                          coarse=coarse)
    return _finite(_top_candidates_jit(models, image, bank, preset=preset, n=n, chunk=chunk, coarse=coarse,
                                       devices=_devices_for(image)))


def refine(models: Models, image: jax.Array, start: Ranking | jax.Array, key: jax.Array, *, preset: Preset,
           method: str = "dmo", R: int = 1, chunk: int | None = None,
           settings: OptimizerSettings = OptimizerSettings()) -> Prediction:
    """Steps 3-4 of :func:`predict`: optimise the starting motions with ``method`` and rank them
    with the results by energy. ``start`` is :func:`top_candidates`' :class:`Ranking` (its F and
    energies are reused) or bare motions, ``[n, 101, 11]`` for an image ``[S, S, 4]`` and
    ``[B, n, 101, 11]`` for images ``[B, S, S, 4]`` (F and their energies are then computed).
    Arguments, result and errors as :func:`predict`."""
    ranking = start if isinstance(start, Ranking) else Ranking(start, None)
    motions, image = (x if hasattr(x, "dtype") else np.asarray(x) for x in (ranking.motions, image))
    shape, image_shape = tuple(jnp.shape(motions)), tuple(jnp.shape(image))
    if (len(shape) not in (3, 4) or len(shape) != len(image_shape) or shape[-2:] != (NUM_STEPS, POSE_DIM)
            or shape[-3] < 1 or (len(shape) == 4 and shape[0] != image_shape[0])):
        raise ValueError(f"start must be [n, {NUM_STEPS}, {POSE_DIM}] for one image or [B, n, {NUM_STEPS}, "
                         f"{POSE_DIM}] for images [B, S, S, 4], got start {shape} for image {image_shape}")
    if ranking.energies is not None and tuple(jnp.shape(ranking.energies)) != shape[:-2]:
        raise ValueError(f"start.energies must be {list(shape[:-2])}, one per motion, got "
                         f"{list(jnp.shape(ranking.energies))}")
    flat = motions.reshape((-1,) + shape[-2:])
    preset, image, _, key, chunk, _ = _checked_call(models, preset, method, image, flat, key, shape[-3], R, chunk,
                                                    "start")
    return _finite(_refine_jit(models, image, ranking._replace(motions=motions), key, preset=preset, method=method,
                               R=R if method in METHODS_USING_R else 0, chunk=chunk, settings=settings))


def _devices_for(image) -> int:
    """:func:`image_devices` for a concrete batch of images; 1 for one image or inside a caller's jit."""
    return image_devices(image.shape[0]) if image.ndim == 4 and is_concrete(image) else 1


def _finite(result):
    """``result`` (a :class:`Prediction` or :class:`Ranking`) if its energies and motions are finite;
    otherwise ``ValueError`` (inside the caller's ``jax.jit`` the values are unknown: not checked).
    Finite inputs give non-finite outputs when the parameters hold NaN or inf, or when motions of
    huge magnitude overflow the networks."""
    energies = result.energies
    motions = result.candidates if isinstance(result, Prediction) else result.motions
    if not is_concrete(energies):
        return result
    bad = count_non_finite(energies) + count_non_finite(motions)
    if bad:
        raise ValueError(f"the networks produced {bad} NaN or inf value(s) in the energies or motions; check that "
                         "the parameters are finite (a diverged training run?) and the motions' magnitudes "
                         "(uv in [-1, 1], z in metres)")
    return result


def applicable_coarse(coarse: CoarseRanking | None, n: int, bank_size: int) -> CoarseRanking | None:
    """``coarse`` where it keeps more than ``n`` and fewer than ``bank_size`` motions, else None
    (the full scoring)."""
    return coarse if coarse is not None and n < coarse.keep < bank_size else None


def resolve_coarse(preset: Preset, coarse: CoarseRanking | None | str, n: int, bank_size: int):
    """The bank scoring a call asks for: ``coarse`` itself, or for ``"preset"`` the preset's
    (:func:`applicable_coarse`)."""
    if isinstance(coarse, str) and coarse == "preset":
        return applicable_coarse(preset.coarse, n, bank_size)
    return coarse


def _checked_call(models, preset, method, image, bank, key, n, R, chunk, bank_name="bank", coarse=None):
    """The argument checks shared by :func:`predict`, :func:`top_candidates` and :func:`refine`
    (``image`` or ``key`` None: not used; ``bank_name``: what the motions are called in errors); returns
    ``(preset, image, bank, key, chunk, coarse)``: arrays, a Preset, the chunk (None: the
    default) and the bank scoring (:func:`resolve_coarse`)."""
    chunk = default_chunk() if chunk is None else chunk
    if isinstance(preset, str):
        preset = get_preset(preset)
    if not isinstance(preset, Preset):
        raise ValueError(f"preset must be a dmo_jax.config.Preset or a preset name, got {type(preset).__name__}")
    for name, value in (("n", n), ("R", R), ("chunk", chunk)):
        if not is_integer(value):
            raise ValueError(f"{name} must be an integer, got {value!r}")
    cache = bank if isinstance(bank, BankCache) else None
    bank = bank if cache is None else cache.motions
    image, bank = (x if x is None or hasattr(x, "dtype") else np.asarray(x) for x in (image, bank))
    coarse = resolve_coarse(preset, coarse, n, jnp.shape(bank)[0] if jnp.ndim(bank) else 0)
    check_request(preset, method, None if image is None else jnp.shape(image), jnp.shape(bank), n, R, coarse)
    if cache is not None:
        pose = cache.pose if hasattr(cache.pose, "dtype") else np.asarray(cache.pose)
        width = preset.head.width * (2 if preset.head.variant == "concat" else 1)
        if tuple(jnp.shape(pose)) != (len(bank), NUM_STEPS, width) or not jnp.issubdtype(pose.dtype, jnp.floating):
            raise ValueError(f"{bank_name}.pose must be floating-point [{len(bank)}, {NUM_STEPS}, {width}] for preset "
                             f"{preset.name!r} (make it with cache_bank), got {describe_array(pose)}")
    if not isinstance(models, Models):
        raise ValueError(f"models must be dmo_jax.inference.Models(ebm, dmo, vae), got {type(models).__name__}")
    if models.ebm is None:
        raise ValueError("every method needs the EBM parameters (Models.ebm)")
    needs = METHOD_REGISTRY[method].needs
    for net in needs:
        if getattr(models, net) is None:
            raise ValueError(f"method {method!r} needs the {_NETWORK_NAMES[net]} parameters (Models.{net})")
    if chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")
    if key is not None:
        key = key if hasattr(key, "dtype") else np.asarray(key)
    check_arrays(image, bank, key, bank_name)
    for net in ("ebm",) + needs:
        check_params(getattr(models, net), preset, net)
    return preset, image, bank if cache is None else BankCache(bank, pose), key, chunk, coarse
