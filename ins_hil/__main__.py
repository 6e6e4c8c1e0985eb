import sys

from ins_hil.cli import main

sys.exit(main())
