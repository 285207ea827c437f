"""``python -m lidard``: run the daemon (same as the ``lidard`` console script)."""

import sys

from .cli import lidard_main

if __name__ == "__main__":
    sys.exit(lidard_main())
