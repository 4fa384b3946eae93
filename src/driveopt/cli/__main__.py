import sys

from driveopt.cli import main

sys.exit(main())
