import sys

from evmotion.cli import main

sys.exit(main())
