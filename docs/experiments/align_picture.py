"""Picture of the residual vertical offset and its correction (stereonet.geometry.align; model card, thirty-third
session) on one data_gen pair (val2ai's first, seed 5252, difficulty 2) whose right view was moved 1 px down: left
image, sgm-refine's error map on the clean pair, on the offset pair, and on the offset pair after auto_align.
    python docs/experiments/align_picture.py [OUT.png]
"""
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from val_sets import load  # noqa: E402

from stereonet.evaluation import apply_fill  # noqa: E402
from stereonet.geometry.align import auto_align  # noqa: E402
from stereonet.matchers import match  # noqa: E402
from stereonet.metrics import evaluate  # noqa: E402
from stereonet.viz import error_map, panel, save_png  # noqa: E402

out_path = sys.argv[1] if len(sys.argv) > 1 else "docs/experiments/align_picture.png"
item = load("val2ai")[0]
left, right = item["left"][None], item["right"][None]
low = torch.cat([right[..., :1, :], right[..., :-1, :]], -2)  # every row one lower (the top row repeated)
aligned, model, corrected = auto_align(left, low, int(item["max_disp"]))
assert corrected, "the offset should have been found"
gt, gt_valid = item["disparity"][None], item["valid"][None]
tiles, titles = [(left[0].permute(1, 2, 0).numpy() * 255).astype(np.uint8)], [f"left ({item['name']})"]
for name, r in (("clean pair", right), ("right view 1 px low", low), (f"aligned ({model.a:+.2f} px fitted)", aligned)):
    with torch.no_grad():
        d = apply_fill(match("sgm-refine", left, r, int(item["max_disp"]))).disparity
    tiles.append(error_map(d[0, 0], gt[0, 0], gt_valid[0, 0]))
    titles.append(f"{name}: bad-2 {evaluate(d, gt, gt_valid, see=False)['bad2']:.2f}")
save_png(out_path, panel(tiles, titles))
print("wrote", out_path)
