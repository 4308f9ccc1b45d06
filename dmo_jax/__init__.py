"""dmo-jax: image-conditioned motion prediction with an energy-based model (EBM) and a
learned Deep Motion Optimizer (DMO), after Oba & Ukita, in JAX/Flax.

The public API is importable from the package root::

    import dmo_jax
    preset = dmo_jax.get_preset("cpu")
    models = dmo_jax.load_models("runs", "pick_up_cup", preset, method="dmo")
    out = dmo_jax.predict(models, image, bank, jax.random.key(0), preset=preset, n=8, R=1)

Names are resolved lazily so that ``import dmo_jax`` does not start JAX: a program that renders
or executes calls ``envs.platform.setup()`` (the GL back-end and XLA flags) before JAX starts.
"""

_EXPORTS = {
    "predict": "inference",
    "top_candidates": "inference",
    "refine": "inference",
    "Models": "inference",
    "Prediction": "inference",
    "Ranking": "inference",
    "BankCache": "inference",
    "cache_bank": "inference",
    "OptimizerSettings": "inference",
    "CoarseRanking": "config",
    "METHODS": "inference",
    "get_preset": "config",
    "PRESETS": "config",
    "VARIANTS": "config",
    "load_models": "workflow",
    "network_image": "data",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'dmo_jax' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
