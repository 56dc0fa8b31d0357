#!/usr/bin/env python
"""Photo pair in, disparity / depth / point cloud out: ``python infer.py LEFT RIGHT -o OUT``.

Thin wrapper: the same ``main`` as the ``stereonet-infer`` console script (stereonet/cli/infer.py).
"""

import sys

from stereonet.cli.infer import main

if __name__ == "__main__":
    sys.exit(main())
