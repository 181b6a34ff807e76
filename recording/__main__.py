"""`python -m recording {info,recover,analyze}`: see recording/cli.py."""
import sys

from .cli import main

sys.exit(main())
