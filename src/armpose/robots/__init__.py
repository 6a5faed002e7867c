"""Robot descriptions (registry) and batched forward kinematics."""
from armpose.robots.registry import (RobotSpec, UnknownRobotError, all_robots, get_robot, register,
                                     register_file)

__all__ = ["RobotSpec", "UnknownRobotError", "all_robots", "get_robot", "register", "register_file"]
