import sys

from windbench.report.cli import main

sys.exit(main())
