"""``python -m unigait``."""

import sys

from unigait.cli import main

sys.exit(main())
