import sys

from link.cli import main

sys.exit(main())
