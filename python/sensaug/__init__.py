"""sensaug: human-robot sensory augmentation (partner identification and goal integration)."""
from sensaug import _core
from sensaug.ukf import PendulumUKF, UkfStepError

__all__ = ["_core", "PendulumUKF", "UkfStepError"]
