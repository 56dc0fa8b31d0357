"""Picture of sgm-refine's weighted median (docs/experiments/wmf.txt) on one held-out data_gen pair (wmfb2's first,
seed 5234, difficulty 2, weak background walls) and on cones (evaluation only): left image, the choice's error map,
the filtered map's error map, and the pixels the filter changed.
    python docs/experiments/wmf_picture.py [OUT.png]
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from val_sets import expand, items, load  # noqa: E402

from stereonet.matchers.learned import sgm_refine_matcher  # noqa: E402
from stereonet.metrics import evaluate  # noqa: E402
from stereonet.viz import error_map, panel, save_png  # noqa: E402

out_path = sys.argv[1] if len(sys.argv) > 1 else "docs/experiments/wmf_picture.png"
cones = next(item for _, item in items(expand("real")) if item["name"].endswith("cones"))
rows = []
for item in (load("wmfb2")[0], cones):
    left, right = item["left"][None], item["right"][None]
    gt, gt_valid = item["disparity"][None], item["valid"][None]
    out = sgm_refine_matcher(left, right, int(item["max_disp"]))
    before, after = out.extras["unfiltered"], out.disparity
    changed = ((after - before).abs() > 0.5)[0, 0].numpy()
    rgb = (left[0].permute(1, 2, 0).numpy() * 255).astype(np.uint8)

    def bad2(d, gt=gt, gt_valid=gt_valid):
        return evaluate(d, gt, gt_valid, see=False)["bad2"]

    rows.append(panel([rgb, error_map(before[0, 0], gt[0, 0], gt_valid[0, 0]),
                       error_map(after[0, 0], gt[0, 0], gt_valid[0, 0]),
                       np.repeat((changed * 255).astype(np.uint8)[..., None], 3, axis=2)],
                      [f"left ({item['name'].split('/')[-1]})", f"choice bad-2 {bad2(before):.2f}",
                       f"+ weighted median bad-2 {bad2(after):.2f}", f"changed by > 0.5 px ({100 * changed.mean():.1f} %)"]))
width = max(r.shape[1] for r in rows)
img = np.concatenate([np.pad(r, ((0, 8), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows])
save_png(out_path, img)
print("wrote", out_path)
