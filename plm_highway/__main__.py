import sys

from plm_highway.cli import main

sys.exit(main())
