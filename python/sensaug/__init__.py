"""sensaug: human-robot sensory augmentation (partner identification and goal integration).

The numerics run in the compiled core (`sensaug._core`, Rust); this package is
the Python API for scripting experiments around it.
"""
from sensaug._core import Plant

__all__ = ["Plant"]
