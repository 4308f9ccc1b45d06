"""Motion representation (docs/method.md, "Data and motion representation").

A motion is ``[T + 1, 11]`` = ``[101, 11]`` float32 pose vectors in the **camera frame**
(OpenCV convention: x right, y down, z forward along the optical axis):

====== ======= ===========================================================
index  name    meaning
====== ======= ===========================================================
0:2    uv      gripper pixel position, normalised ``u / (W - 1) * 2 - 1``
2      z       camera-frame depth of the gripper (metres)
3:9    rot6d   first two ROWS of the camera-frame rotation matrix (Zhou 6D)
9      grasp   gripper state in [0, 1], 1 = open
10     time    normalised time t_i = i / T
====== ======= ===========================================================

Every function here is written with ``jax.numpy`` and works on any leading batch
shape, so it can be jitted and vmapped; ``resample_episode`` is the exception (it
runs once per recorded demonstration, with scipy splines, in numpy).

Pixel coordinates follow the align-corners convention: pixel index ``i`` has its
centre at ``u_px = i``; the normalised coordinate -1 is the centre of the first
pixel and +1 the centre of the last.
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

NUM_STEPS = 101  # T + 1 poses per motion
POSE_DIM = 11

UV = slice(0, 2)
Z = slice(2, 3)
ROT6D = slice(3, 9)
GRASP = slice(9, 10)
TIME = slice(10, 11)

#: Keys in the order of the pose vector, with their slices (used by losses and heads).
POSE_KEYS = {"uv": UV, "z": Z, "rotation": ROT6D, "grasp": GRASP, "time": TIME}


def time_grid(num_steps: int = NUM_STEPS) -> np.ndarray:
    """``[num_steps]`` float32 normalised times ``i / (num_steps - 1)``."""
    return np.linspace(0.0, 1.0, num_steps, dtype=np.float32)


# --------------------------------------------------------------------------- rotations
def matrix_to_rot6d(rot: jnp.ndarray) -> jnp.ndarray:
    """``[..., 3, 3]`` rotation matrices -> ``[..., 6]``: the first two rows, flattened."""
    return rot[..., :2, :].reshape(*rot.shape[:-2], 6)


def rot6d_to_matrix(r6: jnp.ndarray, eps: float = 1e-8) -> jnp.ndarray:
    """``[..., 6]`` -> ``[..., 3, 3]`` by Gram–Schmidt on the two rows (Zhou et al. 2019).

    Row 1 is normalised; row 2 has its component along row 1 removed and is
    normalised; row 3 = row 1 x row 2, so the result is a proper rotation.
    """
    a1, a2 = r6[..., 0:3], r6[..., 3:6]
    b1 = a1 / jnp.maximum(jnp.linalg.norm(a1, axis=-1, keepdims=True), eps)
    a2 = a2 - jnp.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 = a2 / jnp.maximum(jnp.linalg.norm(a2, axis=-1, keepdims=True), eps)
    b3 = jnp.cross(b1, b2)
    return jnp.stack([b1, b2, b3], axis=-2)


# --------------------------------------------------------------------------- pixels
def normalize_uv(uv_px: jnp.ndarray, image_size: int) -> jnp.ndarray:
    """Pixel coordinates (align corners) -> [-1, 1]."""
    return uv_px / (image_size - 1) * 2.0 - 1.0


def denormalize_uv(uv: jnp.ndarray, image_size: int) -> jnp.ndarray:
    """[-1, 1] -> pixel coordinates (align corners)."""
    return (uv + 1.0) * 0.5 * (image_size - 1)


def project(xyz_cam: jnp.ndarray, intrinsics: jnp.ndarray) -> jnp.ndarray:
    """Camera-frame points ``[..., 3]`` -> pixel coordinates ``[..., 2]`` with K ``[3, 3]``."""
    p = xyz_cam @ intrinsics.T
    return p[..., :2] / p[..., 2:3]


def unproject(uv_px: jnp.ndarray, z: jnp.ndarray, intrinsics: jnp.ndarray) -> jnp.ndarray:
    """``xyz = z * K^-1 [u, v, 1]``; ``uv_px [..., 2]``, ``z [..., 1]`` -> ``[..., 3]``."""
    homog = jnp.concatenate([uv_px, jnp.ones_like(z)], axis=-1)
    return z * (homog @ jnp.linalg.inv(intrinsics).T)


# --------------------------------------------------------------------------- poses
def pose_to_vector(
    pos_world: jnp.ndarray,
    rot_world: jnp.ndarray,
    grasp: jnp.ndarray,
    time: jnp.ndarray,
    camera_pos: jnp.ndarray,
    camera_rot: jnp.ndarray,
    intrinsics: jnp.ndarray,
    image_size: int,
) -> jnp.ndarray:
    """World end-effector poses -> camera-frame pose vectors.

    Args:
      pos_world: ``[..., 3]`` positions; rot_world: ``[..., 3, 3]`` orientations (columns
        are the end-effector axes in world coordinates).
      grasp, time: ``[...]`` scalars.
      camera_pos ``[3]``, camera_rot ``[3, 3]``: the camera frame in the world (OpenCV
        axes as columns), intrinsics ``[3, 3]``; image_size: W = H in pixels.
    Returns:
      ``[..., 11]`` pose vectors.
    """
    xyz_cam = (pos_world - camera_pos) @ camera_rot
    rot_cam = jnp.swapaxes(camera_rot, -1, -2) @ rot_world
    uv = normalize_uv(project(xyz_cam, intrinsics), image_size)
    return jnp.concatenate(
        [uv, xyz_cam[..., 2:3], matrix_to_rot6d(rot_cam), grasp[..., None], time[..., None]],
        axis=-1,
    )


def camera_positions(vec: jnp.ndarray, intrinsics: jnp.ndarray, image_size: int) -> jnp.ndarray:
    """Camera-frame positions ``[..., 3]`` (metres) of pose vectors ``[..., 11]``, from (uv, z) with K."""
    return unproject(denormalize_uv(vec[..., UV], image_size), vec[..., Z], intrinsics)


def vector_to_pose(
    vec: jnp.ndarray,
    camera_pos: jnp.ndarray,
    camera_rot: jnp.ndarray,
    intrinsics: jnp.ndarray,
    image_size: int,
) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Camera-frame pose vectors ``[..., 11]`` -> world (position ``[..., 3]``,
    rotation ``[..., 3, 3]``, grasp ``[...]``). The inverse of :func:`pose_to_vector`."""
    pos_world = camera_positions(vec, intrinsics, image_size) @ camera_rot.T + camera_pos
    rot_world = camera_rot @ rot6d_to_matrix(vec[..., ROT6D])
    return pos_world, rot_world, vec[..., 9]


# --------------------------------------------------------------------------- resampling
def resample_episode(
    times: np.ndarray,
    uvz: np.ndarray,
    rotations: np.ndarray,
    grasp: np.ndarray,
    num_steps: int = NUM_STEPS,
) -> np.ndarray:
    """Resample a recorded episode onto ``num_steps`` poses at normalised times i/(num_steps-1).

    Args:
      times: ``[F]`` strictly increasing frame times (any unit; normalised here).
      uvz: ``[F, 3]`` normalised uv and camera-frame z per frame (cubic spline).
      rotations: ``[F, 3, 3]`` camera-frame rotation matrices (rotation spline).
      grasp: ``[F]`` open (1) / closed (0) per frame (linear interpolation).
    Returns:
      ``[num_steps, 11]`` float32 motion.
    """
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import Rotation, RotationSpline

    times = np.asarray(times, np.float64)
    if times.ndim != 1 or times.shape[0] < 2:
        raise ValueError(f"resample_episode needs at least 2 frames, got times of shape {times.shape}")
    if np.any(np.diff(times) <= 0):
        raise ValueError("resample_episode needs strictly increasing frame times")
    t = (times - times[0]) / (times[-1] - times[0])
    grid = time_grid(num_steps).astype(np.float64)
    uvz_s = CubicSpline(t, np.asarray(uvz, np.float64), axis=0)(grid)
    rot_s = RotationSpline(t, Rotation.from_matrix(np.asarray(rotations, np.float64)))(grid).as_matrix()
    grasp_s = np.interp(grid, t, np.asarray(grasp, np.float64))
    out = np.concatenate(
        [uvz_s, rot_s[:, :2, :].reshape(num_steps, 6), grasp_s[:, None], grid[:, None]], axis=-1
    )
    return out.astype(np.float32)


# --------------------------------------------------------------------------- input checks
def count_non_finite(array) -> int:
    """Number of NaN and inf entries of ``array`` (any array-like, read on the host)."""
    a = np.asarray(array)
    return int(a.size - np.count_nonzero(np.isfinite(a)))


def describe_array(array) -> str:
    """``"float32[101, 11]"``: dtype and shape of an array, for error messages."""
    dtype = getattr(array, "dtype", None)
    if dtype is None:
        name = type(array).__name__
    else:
        try:
            name = np.dtype(dtype).name
        except TypeError:  # JAX's extended dtypes (PRNG keys: key<fry>) are not numpy dtypes
            name = str(dtype)
    return f"{name}{list(np.shape(array))}"


def check_motions(motions, what: str = "motions", single: bool = False) -> np.ndarray:
    """``motions`` as a float32 numpy array after checking them; raises ``ValueError`` with
    one line saying what is wrong and what was expected.

    Accepted: real floating-point ``[N, 101, 11]`` (with ``single``: one ``[101, 11]``
    motion, or ``[1, 101, 11]``) holding only finite numbers.
    """
    if not hasattr(motions, "dtype") or not hasattr(motions, "shape"):
        raise ValueError(f"{what} must be an array of motions, got {type(motions).__name__}")
    layout = f"T = {NUM_STEPS} poses of {POSE_DIM} numbers, the [E, T, {POSE_DIM}] layout of envs.motion"
    expected = f"[{NUM_STEPS}, {POSE_DIM}]" if single else f"[N, {NUM_STEPS}, {POSE_DIM}]"
    if not jnp.issubdtype(motions.dtype, jnp.floating):
        raise ValueError(f"{what} must be floating-point {expected} motions, got {describe_array(motions)}")
    shape = tuple(motions.shape)
    if single and len(shape) == 3 and shape[0] == 1:
        shape = shape[1:]
    want_ndim = 2 if single else 3
    if len(shape) != want_ndim or shape[-2:] != (NUM_STEPS, POSE_DIM):
        raise ValueError(f"{what} must be {expected} ({layout}), got {describe_array(motions)}")
    array = np.asarray(motions, np.float32).reshape(shape)
    bad = count_non_finite(array)
    if bad:
        raise ValueError(f"{what} holds {bad} NaN or inf value(s); expected finite numbers")
    return array
