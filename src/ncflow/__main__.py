"""``python -m ncflow``: the ``ncflow`` command."""

import sys

from ncflow.cli import main

sys.exit(main())
