import sys

from kx.native import main

sys.exit(main())
