"""``python -m services.client submit|status|fetch|batch ...``"""

import sys

from .commands import main

sys.exit(main())
