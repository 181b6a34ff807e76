"""`python -m estimation <command>`: see estimation/cli.py."""
import sys

from estimation.cli import main

sys.exit(main())
