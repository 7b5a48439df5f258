"""``python -m bayesian_fields_service.client submit|status|fetch|batch ...``"""

import sys

from bayesian_fields_service.client.commands import main

sys.exit(main())
