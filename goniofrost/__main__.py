import sys

from goniofrost.app.cli import main

sys.exit(main())
