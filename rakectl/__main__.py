import sys

from rakectl.cli.main import main

sys.exit(main())
