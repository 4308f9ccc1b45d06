"""XLA settings the simulator needs, applied before JAX initialises its backend."""
from __future__ import annotations

import os
import sys

# XLA's CPU fusion emitters compile MJX's physics step into a pathologically slow program
# (measured here: ~31 steps/s at batch 16 with them, thousands without). The flag only
# affects the CPU back-end, so it is harmless on accelerators.
_CPU_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def configure_jax_for_cpu() -> None:
    """Append the CPU flags to ``XLA_FLAGS`` unless the user already set them.

    XLA reads the variable when the backend starts, so this is a no-op (with a warning)
    once JAX has created a device.
    """
    current = os.environ.get("XLA_FLAGS", "")
    missing = [f for f in _CPU_FLAGS if f.split("=")[0] not in current]
    if not missing:
        return
    jax = sys.modules.get("jax")
    if jax is not None:
        try:
            from jax._src import xla_bridge

            if xla_bridge.backends_are_initialized():
                return
        except (ImportError, AttributeError):
            pass
    os.environ["XLA_FLAGS"] = " ".join([current, *missing]).strip()
