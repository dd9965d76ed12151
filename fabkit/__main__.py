import sys

from fabkit.cli import main

sys.exit(main())
