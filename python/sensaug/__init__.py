"""sensaug: human-robot sensory augmentation (partner identification and goal integration)."""
from sensaug import _core

__all__ = ["_core"]
