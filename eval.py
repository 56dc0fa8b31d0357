#!/usr/bin/env python
"""Benchmark table for every stereo method: ``python eval.py --methods all --data synthetic:6,real``.

Thin wrapper: the same ``main`` as the ``stereonet-eval`` console script (stereonet/cli/eval.py).
"""

import sys

from stereonet.cli.eval import main

if __name__ == "__main__":
    sys.exit(main())
