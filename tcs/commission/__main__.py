"""``python -m tcs.commission`` = ``tcs-commission``."""

import sys

from tcs.commission.cli import main

sys.exit(main())
