import sys

from vecu.cli import main

sys.exit(main())
