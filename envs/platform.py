"""Process set-up the simulator needs: the headless OpenGL back-end and XLA's settings, applied
before MuJoCo or JAX initialise (:func:`setup`); Python's garbage collector; XLA's compilation
cache."""
from __future__ import annotations

import gc
import os
import sys

from envs.gl import select_gl_backend

# XLA's CPU fusion emitters compile MJX's physics step into a pathologically slow program
# (measured here: ~31 steps/s at batch 16 with them, thousands without). The flag only
# affects the CPU back-end, so it is harmless on accelerators.
_CPU_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def setup() -> None:
    """Select the headless OpenGL back-end (:func:`envs.gl.select_gl_backend`), add XLA's CPU
    flags (:func:`configure_jax_for_cpu`) and collect garbage less often (:func:`collect_garbage_rarely`).

    Must run before mujoco or jax are imported: MuJoCo reads ``MUJOCO_GL`` when its GL module is
    first imported, XLA reads ``XLA_FLAGS`` when JAX starts its backend. Settings the user made
    are kept, and calling it again changes nothing. Every command in ``bin/`` calls it first.
    """
    select_gl_backend()
    configure_jax_for_cpu()
    collect_garbage_rarely()


def collect_garbage_rarely() -> None:
    """Run Python's cyclic garbage collector less often, and leave the objects alive now (the
    libraries imported so far) out of its passes (``gc.freeze``).

    Tracing a JAX program allocates millions of short-lived objects, and with the default
    thresholds (700, 10, 10) the collector runs every few hundred of them: 14-20 % of the time of
    the tests that trace the most, with the same peak memory (BENCHMARKS.md, "Test suite").
    Call it again after the heavy imports to leave them out as well.
    """
    gc.collect()
    gc.freeze()
    gc.set_threshold(50_000, 20, 20)


def add_xla_flag(flag: str) -> bool:
    """Append ``flag`` (``--name=value``) to ``XLA_FLAGS`` unless the variable already names it
    (a value the user set is kept); returns whether it was added."""
    current = os.environ.get("XLA_FLAGS", "")
    if flag.split("=")[0] in current:
        return False
    os.environ["XLA_FLAGS"] = f"{current} {flag}".strip()
    return True


def configure_jax_for_cpu() -> None:
    """Append the CPU flags to ``XLA_FLAGS`` unless the user already set them.

    XLA reads the variable when the backend starts, so once JAX has created a device this
    changes nothing.
    """
    jax = sys.modules.get("jax")
    if jax is not None:
        try:
            from jax._src import xla_bridge

            if xla_bridge.backends_are_initialized():
                return
        except (ImportError, AttributeError):
            pass
    for flag in _CPU_FLAGS:
        add_xla_flag(flag)


def expose_cpu_cores_as_devices() -> None:
    """Make XLA's host platform present one device per core (``bin/train_all``).

    XLA:CPU runs most of a training step's small ops on one thread; data parallelism over
    one device per core uses the others (measured on 2 cores, cpu preset: VAE step 0.50 ->
    0.22 s, EBM step 1.29 -> 0.73 s). Only the host platform reads the flag, so it is
    harmless on accelerators; a device count the user set is kept. Must run before JAX
    initialises its backend.
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if cores > 1:
        add_xla_flag(f"--xla_force_host_platform_device_count={cores}")


def user_cache_dir(name: str) -> str:
    """``~/.cache/dmo_jax/<name>``: where the package keeps what it can rebuild."""
    return os.path.join(os.path.expanduser("~"), ".cache", "dmo_jax", name)


def enable_compilation_cache(min_compile_seconds: float = 0.0) -> str | None:
    """Keep XLA's compiled programs on disk so later runs skip compilation.

    Compiling the cpu preset's three training steps and their evaluations takes about
    1.5 minutes on 2 cores (BENCHMARKS.md); every task after the first, and every resumed run, reuses them
    (the cache key covers the program, the XLA flags and the JAX version). The directory
    is ``$DMO_JAX_COMPILATION_CACHE`` (``off`` disables it), by default
    ``~/.cache/dmo_jax/xla``. Programs that compile in less than ``min_compile_seconds`` are not
    kept. Returns the directory in use, or None.
    """
    path = os.environ.get("DMO_JAX_COMPILATION_CACHE", user_cache_dir("xla"))
    if path.strip().lower() in ("", "off", "0", "none"):
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", path)
    # 0 (the default): also keep the few hundred small programs that run op by op (Flax's
    # initialisers, the optimiser's state): about 25 s of every new process's compilation for the
    # cpu preset's three networks, 7 s when read back (3 MB; BENCHMARKS.md)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_seconds)
    return path
