"""`python -m gma_ffc ...`: the same as the `gma-ffc` command (for a venv not on PATH)."""

import sys

from .cli import main

sys.exit(main())
