"""Headless OpenGL selection for MuJoCo's renderer.

MuJoCo reads ``MUJOCO_GL`` once, when its GL context module is first imported, so the
choice is made before mujoco is imported (``envs.platform.setup``): a user's setting is kept;
otherwise EGL (Mesa's surfaceless llvmpipe works without a GPU) is preferred, then OSMesa.
"""
from __future__ import annotations

import ctypes
import os

_CANDIDATES = (("egl", ("libEGL.so.1", "libEGL.so")), ("osmesa", ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")))
INSTALL_HINT = (
    "install a headless OpenGL library, e.g. `apt-get install libegl-mesa0 libgl1-mesa-dri` (EGL) "
    "or `apt-get install libosmesa6` (OSMesa) — `bin/setup` does this — or set MUJOCO_GL yourself"
)


def _loadable(names: tuple[str, ...]) -> bool:
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def select_gl_backend() -> str | None:
    """Set ``MUJOCO_GL`` to a working headless back-end if unset; return the choice (or None)."""
    if os.environ.get("MUJOCO_GL"):
        backend = os.environ["MUJOCO_GL"]
        if backend == "egl":
            os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
        return backend
    for backend, libs in _CANDIDATES:
        if _loadable(libs):
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    return None
