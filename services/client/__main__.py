"""``python -m bayesian_fields_service.client submit|status|fetch|batch ...``"""

import sys

from bayesian_fields_service.client.verbs import main

sys.exit(main())
