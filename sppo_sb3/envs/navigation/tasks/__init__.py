"""The navigation tasks, by the name in ``Safety<Robot><Task><Level>-v0``."""

from sppo_sb3.envs.navigation.tasks.base import LEVELS, NavigationTask
from sppo_sb3.envs.navigation.tasks.button import ButtonTask
from sppo_sb3.envs.navigation.tasks.circle import CircleTask
from sppo_sb3.envs.navigation.tasks.goal import GoalTask
from sppo_sb3.envs.navigation.tasks.push import PushTask

#: every task, by its name
TASKS: dict[str, type[NavigationTask]] = {task.name: task for task in (GoalTask, ButtonTask, PushTask, CircleTask)}

__all__ = ["LEVELS", "TASKS", "ButtonTask", "CircleTask", "GoalTask", "NavigationTask", "PushTask"]
