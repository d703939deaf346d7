import sys

from cfstack.cli import main

sys.exit(main())
