"""The front camera: projection with K and pose lands on the rendered gripper; metric depth."""
import mujoco
import numpy as np
import pytest

from envs import camera, panda
from envs.execution import World

POSTURES = [
    panda.HOME_QPOS,
    (0.5, 0.2, 0.0, -1.9, 0.0, 2.1, 0.785),
    (-0.6, 0.4, 0.2, -1.6, 0.1, 2.0, 0.3),
    (0.2, 0.6, -0.3, -1.3, 0.0, 1.9, 1.2),
]


@pytest.fixture(scope="module", params=[256, 128])
def marked(request):
    world = World.from_xml(panda.default_scene_xml(tcp_marker=True), request.param)
    renderer = camera.SceneRenderer(world.model, request.param)
    yield world, renderer
    renderer.close()


@pytest.mark.parametrize("posture", POSTURES)
def test_projected_tcp_lands_on_rendered_marker(marked, posture):
    world, renderer = marked
    model = world.model
    data = mujoco.MjData(model)
    data.qpos[:] = world.home_qpos()  # fingers open, so they do not hide the marker
    data.qpos[world.chain.qpos_index] = posture
    mujoco.mj_forward(model, data)
    marker = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "tcp_marker")
    seg = renderer.segmentation(data)
    rows, cols = np.nonzero(seg == marker)
    assert len(rows) > 0, "the TCP marker is not visible"
    tcp = data.site("tcp").xpos
    uv = world.camera.project(tcp)
    centroid = np.array([cols.mean(), rows.mean()])
    assert np.linalg.norm(uv - centroid) < 2.0, (uv, centroid)
    _, depth = renderer.rgbd(data)
    z = world.camera.world_to_camera(tcp)[2]
    assert abs(np.median(depth[rows, cols]) - z) < 0.01


def test_intrinsics_and_pose_come_from_the_model():
    world = World.from_xml(panda.default_scene_xml(), 128)
    cam = world.camera
    k = cam.intrinsics
    assert k[0, 2] == k[1, 2] == pytest.approx(63.5)
    assert 2 * np.degrees(np.arctan(64 / k[1, 1])) == pytest.approx(panda.CAMERA_FOVY)
    np.testing.assert_allclose(cam.position, panda.CAMERA_POS)
    np.testing.assert_allclose(cam.rotation.T @ cam.rotation, np.eye(3), atol=1e-9)
    # Looking forward (+z) at the target, image "down" (+y) pointing down in the world.
    forward = np.subtract(panda.CAMERA_TARGET, panda.CAMERA_POS)
    np.testing.assert_allclose(cam.rotation[:, 2], forward / np.linalg.norm(forward), atol=1e-6)
    assert cam.rotation[2, 1] < 0


def test_rgbd_shapes_and_types():
    world = World.from_xml(panda.default_scene_xml(), 64)
    data = mujoco.MjData(world.model)
    mujoco.mj_forward(world.model, data)
    with camera.SceneRenderer(world.model, 64) as r:
        rgb, depth = r.rgbd(data)
        np.testing.assert_array_equal(r.rgb(data), rgb)  # the colour image alone is the same
    assert rgb.shape == (64, 64, 3) and rgb.dtype == np.uint8
    assert depth.shape == (64, 64) and depth.dtype == np.float32
    assert 1.0 < depth[32, 32] < 3.0  # the table in the middle of the view, metres away


def test_renderer_rejects_bad_sizes():
    world = World.from_xml(panda.default_scene_xml(), 64)
    with pytest.raises(ValueError, match="image size"):
        camera.SceneRenderer(world.model, 4096)


def test_write_png_is_atomic_and_valid(tmp_path):
    import imageio.v3 as iio

    img = np.random.default_rng(0).integers(0, 255, (7, 5, 3), dtype=np.uint8)
    out = tmp_path / "x.png"
    camera.write_png(out, img)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(data[16:20], "big") == 5 and int.from_bytes(data[20:24], "big") == 7
    np.testing.assert_array_equal(iio.imread(out), img)  # lossless
    assert list(tmp_path.iterdir()) == [out]
    with pytest.raises(ValueError, match="H, W, 3"):
        camera.write_png(out, img[..., 0])
