"""PC: pick up the red cup; a blue distractor cup stands at least 0.1 m away."""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import DOWN, Task

HALF = 0.028  # half side of the cup's square collision prism (the visual is a cylinder)
HEIGHT = 0.05  # half height
REGION = (np.array([0.35, -0.3]), np.array([0.65, 0.3]))


def _cup(name: str, rgba: str) -> str:
    return (
        f'<body name="{name}" pos="0.5 0 {panda.TABLE_HEIGHT + HEIGHT}"><freejoint name="{name}"/>'
        f'<geom name="{name}" type="box" size="{HALF} {HALF} {HEIGHT}" mass="0.12" class="object" rgba="0 0 0 0"/>'
        f'<geom name="{name}_vis" type="cylinder" size="{HALF * 1.15:.4f} {HEIGHT}" class="visual" rgba="{rgba}"/>'
        f'<geom name="{name}_rim" type="cylinder" size="{HALF * 0.95:.4f} 0.002" pos="0 0 {HEIGHT}" class="visual" '
        f'rgba="0.1 0.1 0.1 1"/></body>'
    )


class PickUpCup(Task):
    name = "pick_up_cup"
    abbr = "PC"

    def scene_xml(self) -> str:
        objects = _cup("cup", "0.85 0.15 0.1 1") + _cup("distractor", "0.15 0.3 0.85 1")
        pairs = tuple((g, c) for c in ("cup", "distractor") for g in ("table", *panda.GRIPPER_GEOMS))
        return panda.scene_xml(objects=objects, pairs=pairs + (("cup", "distractor"),))

    def randomize(self, rng):
        while True:
            cup, other = rng.uniform(*REGION, (2, 2))
            if np.linalg.norm(cup - other) >= 0.1:
                return {"cup": cup, "distractor": other}

    def place(self, params, qpos, body_pos, body_quat):
        for name in ("cup", "distractor"):
            self.set_free(qpos, name, (*params[name], panda.TABLE_HEIGHT + HEIGHT))

    def success(self, qpos, scenes):
        start = self.free_pose(scenes.qpos, "cup")[0][:, None]
        pos = self.free_pose(qpos, "cup")[0]
        left = np.linalg.norm(pos - start, axis=-1) > 0.05
        return left & self.held(qpos, pos, HALF)

    def expert_keyframes(self, scene):
        x, y = scene.params["cup"]
        grip = panda.TABLE_HEIGHT + HEIGHT + 0.01
        return [
            Keyframe((x, y, grip + 0.15), DOWN, 1.0, 1.5),
            Keyframe((x, y, grip), DOWN, 1.0, 1.0),
            Keyframe((x, y, grip), DOWN, 0.0, 0.6),
            Keyframe((x, y, grip + 0.2), DOWN, 0.0, 1.4),
        ]
