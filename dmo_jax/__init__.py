"""dmo-jax: image-conditioned motion prediction with an energy-based model (EBM) and a
learned Deep Motion Optimizer (DMO), after Oba & Ukita, in JAX/Flax."""
