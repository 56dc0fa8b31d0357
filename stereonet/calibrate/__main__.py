"""``python -m stereonet.calibrate LEFT RIGHT --board COLSxROWS --square SIZE -o CALIB.yaml``.

Thin wrapper: the same ``main`` as the ``stereonet-calibrate`` console script (stereonet/cli/calibrate.py).
"""

import sys

from stereonet.cli.calibrate import main

if __name__ == "__main__":
    sys.exit(main())
