"""Timing and cost helpers the benchmarks share: wall time after compilation, XLA's FLOP
and memory counts, the machine's name."""
from __future__ import annotations

import platform
import time

import jax


def time_call(fn, *args, repeats: int = 10, warmup: int = 2) -> list[float]:
    """Wall-clock seconds of ``fn(*args)`` (blocked until ready) for each of ``repeats`` runs."""
    for _ in range(warmup):
        jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return times


def compiled_flops(fn, *args) -> float:
    analysis = jax.jit(fn).lower(*args).compile().cost_analysis()
    if isinstance(analysis, (list, tuple)):
        analysis = analysis[0]
    return float(analysis["flops"])


def peak_bytes(fn, *args) -> int | None:
    """Temporary + output + argument bytes of the compiled ``fn`` (XLA's memory analysis)."""
    try:
        m = jax.jit(fn).lower(*args).compile().memory_analysis()
        return int(m.temp_size_in_bytes + m.output_size_in_bytes + m.argument_size_in_bytes)
    except Exception:  # not every back-end reports it
        return None


def megabytes(nbytes):
    return None if nbytes is None else round(nbytes / 2**20, 1)


def cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()
