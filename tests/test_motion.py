"""Motion representation: round trips between world poses, camera-frame vectors, 6D and pixels."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from envs import demo
from envs import motion as M

FLOATS = st.floats(-1.0, 1.0, allow_nan=False, width=32)
WORLD = demo.default_world(256)
CAM = WORLD.camera


def _rotation(quat):
    q = np.asarray(quat, np.float64)
    if np.linalg.norm(q) < 1e-3:
        q = np.array([0.0, 0, 0, 1])
    return Rotation.from_quat(q).as_matrix()


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, 4, elements=FLOATS))
def test_rot6d_roundtrip(quat):
    rot = _rotation(quat)
    back = np.asarray(M.rot6d_to_matrix(M.matrix_to_rot6d(rot.astype(np.float32))))
    np.testing.assert_allclose(back, rot, atol=1e-5)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, 6, elements=st.floats(-5, 5, allow_nan=False)))
def test_gram_schmidt_gives_rotation(r6):
    a1, a2 = r6[:3], r6[3:]
    # Skip degenerate inputs (a zero or nearly parallel pair has no defined frame).
    if np.linalg.norm(a1) < 1e-2 or np.linalg.norm(np.cross(a1, a2)) < 1e-2 * np.linalg.norm(a1):
        return
    rot = np.asarray(M.rot6d_to_matrix(r6.astype(np.float32)), np.float64)
    # float32 orthogonality error grows like eps / sin(angle(a1, a2)); the angle is >= 1e-2 here
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-4)
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-4)
    # The first row keeps the direction of a1.
    np.testing.assert_allclose(rot[0], a1 / np.linalg.norm(a1), atol=1e-5)


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, 2, elements=st.floats(0, 255, allow_nan=False)),
    st.floats(0.3, 4.0),
    st.floats(100, 600),
)
def test_uvz_xyz_roundtrip(uv_px, z, focal):
    k = np.array([[focal, 0, 127.5], [0, focal, 127.5], [0, 0, 1]], np.float32)
    xyz = M.unproject(uv_px.astype(np.float32), np.array([z], np.float32), k)
    assert float(xyz[2]) == pytest.approx(z, rel=1e-5)
    np.testing.assert_allclose(M.project(xyz, k), uv_px, atol=2e-3)
    np.testing.assert_allclose(M.denormalize_uv(M.normalize_uv(uv_px, 256), 256), uv_px, atol=1e-4)


def test_normalized_uv_uses_align_corners():
    np.testing.assert_allclose(M.normalize_uv(np.array([0.0, 255.0]), 256), [-1.0, 1.0])


@settings(max_examples=40, deadline=None)
@given(
    st.floats(0.2, 0.8), st.floats(-0.4, 0.4), st.floats(0.76, 1.3),
    arrays(np.float64, 4, elements=FLOATS), st.floats(0, 1), st.floats(0, 1),
)
def test_world_pose_vector_roundtrip(x, y, z, quat, grasp, time):
    pos, rot = np.array([x, y, z]), _rotation(quat)
    args = (CAM.position, CAM.rotation, CAM.intrinsics, CAM.image_size)
    vec = M.pose_to_vector(pos, rot, np.float64(grasp), np.float64(time), *args)
    assert vec.shape == (M.POSE_DIM,)
    # The camera frame agrees with the camera's own projection (denormalize_uv computes in float32).
    np.testing.assert_allclose(M.denormalize_uv(vec[M.UV], 256), CAM.project(pos), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(vec[M.Z], CAM.world_to_camera(pos)[2:], atol=1e-9)
    pos2, rot2, grasp2 = M.vector_to_pose(vec, *args)
    np.testing.assert_allclose(pos2, pos, atol=1e-6)
    np.testing.assert_allclose(rot2, rot, atol=1e-6)
    assert float(grasp2) == pytest.approx(grasp)
    assert float(vec[10]) == pytest.approx(time)


@settings(max_examples=25, deadline=None)
@given(st.integers(5, 400), arrays(np.float64, 3, elements=FLOATS), arrays(np.float64, 3, elements=FLOATS))
def test_resample_reproduces_smooth_trajectories(frames, a, b):
    """Cubic positions and constant-rate rotations are reproduced exactly by the splines."""
    t = np.sort(np.random.default_rng(frames).uniform(0, 5, frames))
    t = np.unique(np.concatenate([[0.0], t, [5.0]]))
    s = (t - t[0]) / (t[-1] - t[0])
    uvz = a[None] * s[:, None] ** 2 + b[None] * s[:, None]
    rotvec = np.array([0.3, -0.2, 0.5])
    rots = Rotation.from_rotvec(s[:, None] * rotvec).as_matrix()
    grasp = (s < 0.5).astype(float)
    out = M.resample_episode(t, uvz, rots, grasp)
    grid = M.time_grid().astype(np.float64)
    assert out.shape == (M.NUM_STEPS, M.POSE_DIM) and out.dtype == np.float32
    np.testing.assert_allclose(out[:, M.TIME][:, 0], grid, atol=1e-7)
    np.testing.assert_allclose(out[:, 0:3], a * grid[:, None] ** 2 + b * grid[:, None], atol=1e-4)
    expected = Rotation.from_rotvec(grid[:, None] * rotvec).as_matrix()
    np.testing.assert_allclose(M.rot6d_to_matrix(out[:, M.ROT6D]), expected, atol=1e-4)
    assert out[0, 9] == 1.0 and out[-1, 9] == 0.0
    assert np.all((out[:, 9] >= 0) & (out[:, 9] <= 1))


def test_resample_gripper_is_linear_across_a_switch():
    t = np.arange(5, dtype=float)  # frames at s = 0, .25, .5, .75, 1
    rots = np.tile(np.eye(3), (5, 1, 1))
    out = M.resample_episode(t, np.zeros((5, 3)), rots, np.array([1, 1, 0, 0, 0.0]))
    # Between s = .25 (open) and .5 (closed) the grasp falls linearly: fractional values.
    i = 30  # s = 0.3
    assert out[i, 9] == pytest.approx(1 - (0.3 - 0.25) / 0.25, abs=1e-5)


def test_resample_rejects_bad_times():
    rots = np.tile(np.eye(3), (3, 1, 1))
    with pytest.raises(ValueError, match="increasing"):
        M.resample_episode(np.array([0.0, 1.0, 1.0]), np.zeros((3, 3)), rots, np.ones(3))
    with pytest.raises(ValueError, match="at least 2"):
        M.resample_episode(np.array([0.0]), np.zeros((1, 3)), rots[:1], np.ones(1))
