import sys

from rakectl.cli import main

sys.exit(main())
