import sys

from bayesdamper.cli import main

sys.exit(main())
