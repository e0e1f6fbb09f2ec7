import sys

from ncflow.cli import main

sys.exit(main())
