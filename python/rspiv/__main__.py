import sys

from rspiv.cli import main

sys.exit(main())
