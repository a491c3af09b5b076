import sys

from rft_mujoco.studies.cli import main

sys.exit(main())
