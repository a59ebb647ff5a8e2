"""``python -m vtestbed``: the same as the ``vtestbed`` command."""

import sys

from .cli.main import main

sys.exit(main())
