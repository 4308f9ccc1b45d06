"""The nine tasks of the paper (RLBench's), rebuilt in MuJoCo. ``get_task(name)`` builds one."""
from __future__ import annotations

from envs.tasks.base import Scene, Task
from envs.tasks.close_box import CloseBox
from envs.tasks.pick_up_cup import PickUpCup
from envs.tasks.push_button import PushButton
from envs.tasks.put_knife_on_chopping_board import PutKnifeOnChoppingBoard
from envs.tasks.put_rubbish_in_bin import PutRubbishInBin
from envs.tasks.put_umbrella_in_umbrella_stand import PutUmbrellaInUmbrellaStand
from envs.tasks.reach_target import ReachTarget
from envs.tasks.stack_wine import StackWine
from envs.tasks.take_plate_off_colored_dish_rack import TakePlateOffColoredDishRack

_ALL = (
    CloseBox,
    PickUpCup,
    PushButton,
    PutKnifeOnChoppingBoard,
    PutRubbishInBin,
    PutUmbrellaInUmbrellaStand,
    ReachTarget,
    StackWine,
    TakePlateOffColoredDishRack,
)
#: name -> task class, in the paper's column order.
TASKS: dict[str, type[Task]] = {cls.name: cls for cls in _ALL}


def get_task(name: str, image_size: int = 256) -> Task:
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; expected one of: {', '.join(TASKS)}")
    return TASKS[name](image_size)


__all__ = ["Scene", "Task", "TASKS", "get_task"]
