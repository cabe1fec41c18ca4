"""sensaug: human-robot sensory augmentation (partner identification and goal integration).

The numerics run in the compiled core (`sensaug._core`, Rust); this package is
the Python API for scripting experiments around it.
"""
from sensaug import _core
from sensaug._core import GainEstimator, GoalIntegrator, Plant, TrajectoryEstimator, UkfStepError
from sensaug.config import PhaseConfig, ScenarioConfig
from sensaug.experiment import Trial, run
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
    "GainEstimator",
    "GoalIntegrator",
    "PhaseConfig",
    "Plant",
    "RiccatiConvergenceError",
    "ScenarioConfig",
    "TrajectoryEstimator",
    "Trial",
    "UkfStepError",
    "agent_gains",
    "care",
    "dare",
    "lqr",
    "partner_gain_vector",
    "robot_gain_vector",
    "run",
]
