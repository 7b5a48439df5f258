"""`python -m bayesian_fields_core.cli`: the same as the `bfields` script."""

import sys

from bayesian_fields_core.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
