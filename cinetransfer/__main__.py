import sys

from cinetransfer.cli import main

sys.exit(main())
