"""`python -m bayesian_fields_core.cli`: the same as the `bfields` script."""

import sys

from bayesian_fields_core.cli.main import main

if __name__ == "__main__":  # importing the module (e.g. walking the package) must not run the CLI
    sys.exit(main())
