"""``python -m sensaug``: see :mod:`sensaug.cli`."""
import sys

from sensaug.cli import main

sys.exit(main())
