"""The fixed front camera: intrinsics and pose read from the model, RGB-D rendering.

Conventions: the camera frame is OpenCV's (x right, y down, z forward); pixel index
``i`` has its centre at coordinate ``i`` (align corners), so the principal point of a
W-pixel image is ``(W - 1) / 2``. Depth is metric distance along the optical axis
(the camera-frame z), float32 metres.
"""
from __future__ import annotations

import dataclasses
import os
import secrets
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from envs import gl
from envs.panda import CAMERA_NAME

# MuJoCo cameras look along -z with y up; OpenCV looks along +z with y down.
_MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole camera: ``intrinsics`` K ``[3, 3]``, world ``position [3]`` and ``rotation [3, 3]``
    (columns are the OpenCV camera axes in world coordinates), square ``image_size``."""

    intrinsics: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    image_size: int

    def world_to_camera(self, xyz_world: np.ndarray) -> np.ndarray:
        return (np.asarray(xyz_world) - self.position) @ self.rotation

    def project(self, xyz_world: np.ndarray) -> np.ndarray:
        """World points ``[..., 3]`` -> pixel coordinates ``[..., 2]`` (u = column, v = row)."""
        p = self.world_to_camera(xyz_world) @ self.intrinsics.T
        return p[..., :2] / p[..., 2:3]


def front_camera(model: mujoco.MjModel, image_size: int = 256, name: str = CAMERA_NAME) -> Camera:
    """The named camera of ``model`` at ``image_size`` x ``image_size`` pixels."""
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cam_id < 0:
        raise ValueError(f"the model has no camera named {name!r}")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    focal = 0.5 * image_size / np.tan(np.deg2rad(model.cam_fovy[cam_id]) / 2)
    centre = (image_size - 1) / 2
    intrinsics = np.array([[focal, 0, centre], [0, focal, centre], [0, 0, 1]])
    rotation = data.cam_xmat[cam_id].reshape(3, 3) @ _MUJOCO_TO_OPENCV
    return Camera(intrinsics, data.cam_xpos[cam_id].copy(), rotation, image_size)


class SceneRenderer:
    """Renders RGB (uint8 ``[S, S, 3]``), depth (float32 metres ``[S, S]``) and segmentation
    (int32 geom ids ``[S, S]``, -1 for background) from the front camera."""

    def __init__(self, model: mujoco.MjModel, image_size: int = 256, camera: str = CAMERA_NAME):
        limit = min(model.vis.global_.offwidth, model.vis.global_.offheight)
        if not 1 <= image_size <= limit:
            raise ValueError(f"image size must be between 1 and {limit} pixels, got {image_size}")
        try:
            self._renderer = mujoco.Renderer(model, image_size, image_size)
        except Exception as err:  # mujoco raises several types when no GL context can be made
            backend = os.environ.get("MUJOCO_GL")
            setup = "" if backend else "call envs.platform.setup() before mujoco is imported, or "
            raise RuntimeError(
                f"cannot create an OpenGL context for rendering (MUJOCO_GL={backend!r}): "
                f"{err}. To fix: {setup}{gl.INSTALL_HINT}"
            ) from err
        self._camera = camera
        self.model = model

    def _render(self, data: mujoco.MjData, depth: bool = False, segmentation: bool = False) -> np.ndarray:
        r = self._renderer
        r.enable_depth_rendering() if depth else r.disable_depth_rendering()
        r.enable_segmentation_rendering() if segmentation else r.disable_segmentation_rendering()
        r.update_scene(data, self._camera)
        return r.render()

    def rgb(self, data: mujoco.MjData) -> np.ndarray:
        """uint8 ``[H, W, 3]``: the colour image alone, half the rendering of :meth:`rgbd`."""
        return self._render(data).copy()

    def rgbd(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        return self.rgb(data), self._render(data, depth=True).astype(np.float32)

    def segmentation(self, data: mujoco.MjData) -> np.ndarray:
        seg = self._render(data, segmentation=True)
        ids = seg[..., 0].astype(np.int32)
        return np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), ids, -1)

    def close(self) -> None:
        self._renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def depth_to_rgb(depth: np.ndarray, near: float | None = None, far: float | None = None) -> np.ndarray:
    """Grey-scale visualisation of metric depth (near = bright)."""
    near = float(depth.min()) if near is None else near
    far = min(float(depth.max()), near + 2.5) if far is None else far  # the sky is ~100 m away
    scaled = 1.0 - np.clip((depth - near) / max(far - near, 1e-6), 0, 1)
    return np.repeat((scaled * 255).astype(np.uint8)[..., None], 3, axis=-1)


def write_atomically(path: str | Path, write: Callable[[Path], None]) -> None:
    """Call ``write(tmp)`` with a fresh temporary name beside ``path``, then rename it to ``path``:
    readers see the old file or the whole new one, never a part. The temporary file is removed
    if ``write`` fails."""
    path = Path(path)
    # A unique name that ``write`` creates itself (so the file gets the usual permissions),
    # ending in ``path``'s suffix for writers that choose the format by it.
    tmp = path.with_name(f".{path.stem}.{os.getpid()}-{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write a uint8 ``[H, W, 3]`` image as PNG, atomically (temporary name, then rename)."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"write_png expects a [H, W, 3] uint8 image, got shape {rgb.shape}")
    import imageio.v3 as iio

    write_atomically(path, lambda tmp: iio.imwrite(tmp, rgb, extension=".png", plugin="pillow"))
