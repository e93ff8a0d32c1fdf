"""ManiSkill tasks of maniskill_pnp; importing this module registers every task id with ManiSkill and gymnasium."""

from maniskill_pnp.tasks.clutter_grasp import LOSS_CAUSES, ClutterGraspEnv
from maniskill_pnp.tasks.clutter_grasp_slide import ClutterGraspSlideEnv
from maniskill_pnp.tasks.conveyor import ConveyorProximityEnv
from maniskill_pnp.tasks.cube_to_bin import CubeToBinEnv
from maniskill_pnp.tasks.primitive_env import OUTCOME_KEYS

TASK_IDS = ("CubeToBin-v1", "ConveyorProximity-v1", "ClutterGrasp-v1", "ClutterGraspSlide-v1")

__all__ = ["ClutterGraspEnv", "ClutterGraspSlideEnv", "ConveyorProximityEnv", "CubeToBinEnv", "LOSS_CAUSES", "OUTCOME_KEYS",
           "TASK_IDS"]
