#!/usr/bin/env python3
"""Mean FLIP (NVIDIA's perceptual image difference, LDR) of TEST against
REFERENCE, two image files: printed as one number (update_test's images).

usage: flip_mean.py REFERENCE TEST
"""
import sys

import flip_evaluator as flip

if len(sys.argv) != 3:
    sys.exit(__doc__.strip())
_, mean, _ = flip.evaluate(sys.argv[1], sys.argv[2], "LDR")
print(f"{mean:.6f}")
