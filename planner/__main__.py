"""`python -m planner <command>`: see planner/cli/ for the commands."""
import sys

from planner.cli import main

sys.exit(main())
