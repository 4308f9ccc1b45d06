"""RT: reach the red target sphere; two distractor spheres are placed at least 0.2 m away."""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.tasks.base import DOWN, Task
from envs.scripted import Keyframe

RADIUS = 0.03
LOW = np.array([0.3, -0.3, panda.TABLE_HEIGHT + 0.08])
HIGH = np.array([0.65, 0.3, panda.TABLE_HEIGHT + 0.35])
COLOURS = {"target": "0.9 0.1 0.1 1", "distractor_a": "0.1 0.7 0.2 1", "distractor_b": "0.15 0.3 0.9 1"}


class ReachTarget(Task):
    name = "reach_target"
    abbr = "RT"

    def scene_xml(self) -> str:
        spheres = "".join(
            f'<body name="{n}" pos="0.5 0 1"><geom name="{n}" type="sphere" size="{RADIUS}" class="visual" '
            f'rgba="{c}"/></body>'
            for n, c in COLOURS.items()
        )
        return panda.scene_xml(objects=spheres)

    def randomize(self, rng):
        # Rejection sampling: all three spheres pairwise >= 0.2 m apart (RLBench's rule).
        while True:
            pts = rng.uniform(LOW, HIGH, (3, 3))
            if min(np.linalg.norm(pts[i] - pts[j]) for i, j in ((0, 1), (0, 2), (1, 2))) >= 0.2:
                return {"positions": pts}

    def place(self, params, qpos, body_pos, body_quat):
        for name, p in zip(COLOURS, params["positions"]):
            body_pos[self.body_id(name)] = p

    def success(self, qpos, scenes):
        target = scenes.body_pos[:, self.body_id("target")][:, None]
        tcp, _ = self.tcp_pose(qpos)
        return np.linalg.norm(tcp - target, axis=-1) < RADIUS

    def expert_keyframes(self, scene):
        target = tuple(scene.params["positions"][0])
        return [Keyframe(target, DOWN, 1.0, 2.0), Keyframe(target, DOWN, 1.0, 0.5)]
