import sys

from kx.hyperneat.native import main

sys.exit(main())
