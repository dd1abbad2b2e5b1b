import sys

from sb3_macb.cli import main

sys.exit(main())
