"""Picture of sgm-refine's per-pixel choice on one held-out data_gen pair (val2b's first, seed 5152, difficulty 2):
left image, error maps of siamese-census-sgm, sgm and the choice, and where the choice took sgm's value.
    python docs/experiments/choice_picture.py [OUT.png]
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from val_sets import load  # noqa: E402

from stereonet.matchers.learned import refine_bases, sgm_refine_matcher  # noqa: E402
from stereonet.metrics import evaluate  # noqa: E402
from stereonet.viz import error_map, panel, save_png  # noqa: E402

out_path = sys.argv[1] if len(sys.argv) > 1 else "docs/experiments/sgm_refine_choice.png"
item = load("val2b")[0]
left, right = item["left"][None], item["right"][None]
gt, gt_valid, max_disp = item["disparity"][None], item["valid"][None], int(item["max_disp"])
maps, _, _ = refine_bases(("siamese-census-sgm", "sgm"), left, right, max_disp)
chosen = sgm_refine_matcher(left, right, max_disp, wmf_radius=0).disparity  # the choice itself, before its filter
took_sgm = (chosen == maps[:, 1:]) & (chosen != maps[:, :1])
rgb = (left[0].permute(1, 2, 0).numpy() * 255).astype(np.uint8)
mask = np.repeat((took_sgm[0, 0].numpy() * 255).astype(np.uint8)[..., None], 3, axis=2)


def bad2(d) -> float:
    return evaluate(d, gt, gt_valid, see=False)["bad2"]


img = panel([rgb, error_map(maps[0, 0], gt[0, 0], gt_valid[0, 0]), error_map(maps[0, 1], gt[0, 0], gt_valid[0, 0]),
             error_map(chosen[0, 0], gt[0, 0], gt_valid[0, 0]), mask],
            [f"left ({item['name']})", f"siamese-census-sgm bad-2 {bad2(maps[:, :1]):.1f}",
             f"sgm bad-2 {bad2(maps[:, 1:]):.1f}", f"choice bad-2 {bad2(chosen):.1f}",
             f"where it took sgm's value ({float(took_sgm.float().mean() * 100):.1f} %)"])
save_png(out_path, img)
print("wrote", out_path)
