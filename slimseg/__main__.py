import sys

from slimseg.cli.main import main

sys.exit(main())
