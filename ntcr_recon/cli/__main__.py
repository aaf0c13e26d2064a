"""`python -m ntcr_recon.cli ...`, the same as the `ntcr-recon` console script."""

import sys

from ntcr_recon.cli import main

sys.exit(main())
