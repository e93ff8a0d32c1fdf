"""Motion planning for the Panda: FCL collision world from the ManiSkill scene, IK, OMPL RRT-Connect,
time parameterization, execution, and the pick / place / slide primitives built on them."""

from maniskill_pnp.planning.collision import CollisionWorld
from maniskill_pnp.planning.executor import SimExecutor
from maniskill_pnp.planning.lockstep import LockstepExecutor, Motion, PaddedTrajectories, Program, drive, pad_trajectories
from maniskill_pnp.planning.kinematics import IKResult, Kinematics, SegmentResult
from maniskill_pnp.planning.primitives import MotionPrimitives, PlaceRegion, PrimitiveResult, grasp_pose
from maniskill_pnp.planning.robot import ArmSpec, panda_spec
from maniskill_pnp.planning.rrt import JointSpacePlanner, PlanCache, PlanResult

__all__ = [
    "ArmSpec", "CollisionWorld", "IKResult", "JointSpacePlanner", "Kinematics", "LockstepExecutor", "Motion", "MotionPrimitives",
    "PaddedTrajectories", "Program", "PlaceRegion", "PlanCache", "PlanResult", "PrimitiveResult", "SegmentResult", "SimExecutor",
    "drive", "grasp_pose", "pad_trajectories", "panda_spec",
]
