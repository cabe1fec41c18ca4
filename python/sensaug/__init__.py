"""sensaug: human-robot sensory augmentation (partner identification and goal integration).

The numerics run in the compiled core (`sensaug._core`, Rust); this package is
the Python API for scripting experiments around it.
"""
from sensaug import _core
from sensaug._resources import package_version
from sensaug._core import UkfStepError
from sensaug.config import ConfigError, PhaseConfig, ScenarioConfig
from sensaug.estimators import GainEstimator, GoalIntegrator, Plant, TrajectoryEstimator
from sensaug.experiment import Trial, run
from sensaug.logs import Log, load_log
from sensaug.lqr import (
    RiccatiConvergenceError,
    agent_gains,
    care,
    dare,
    lqr,
    partner_gain_vector,
    robot_gain_vector,
)
from sensaug.replay import replay
from sensaug.session import load_session
from sensaug.sweep import sweep

#: The installed version (package metadata; the Cargo workspace version).
__version__ = package_version()

__all__ = [
    "__version__",
    "_core",
    "ConfigError",
    "GainEstimator",
    "GoalIntegrator",
    "Log",
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
    "load_log",
    "load_session",
    "lqr",
    "partner_gain_vector",
    "replay",
    "robot_gain_vector",
    "run",
    "sweep",
]
