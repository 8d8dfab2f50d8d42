"""``python -m voro3d``: the ``voro3d`` command."""
import sys

from .cli import main

sys.exit(main())
