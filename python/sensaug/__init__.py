"""sensaug: human-robot sensory augmentation (partner identification and goal integration)."""
from sensaug import _core
from sensaug.lqr import (
    RiccatiConvergenceError,
    agent_gains,
    care,
    dare,
    lqr,
    partner_gain_vector,
    robot_gain_vector,
)

__all__ = [
    "_core",
    "RiccatiConvergenceError",
    "agent_gains",
    "care",
    "dare",
    "lqr",
    "partner_gain_vector",
    "robot_gain_vector",
]
