"""``python -m advocc_ros.orchestrator``: the ``orchestrator`` executable."""

import sys

from advocc_ros.orchestrator.cli import main

sys.exit(main())
