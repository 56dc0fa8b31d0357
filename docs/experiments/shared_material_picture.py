"""The picture of data_gen's shared_material option (twenty-fifth session): three shm32 pairs (seed 5174, difficulty 2),
each row the left view without the shared looks, with them (p = 0.5), and the ground-truth disparity (same geometry).
Run: python docs/experiments/shared_material_picture.py [OUT.png]"""
import sys

import cv2
import numpy as np

import data_gen


def rgb(t):
    return (t.permute(1, 2, 0).numpy()[..., ::-1] * 255).round().astype(np.uint8)


rows = []
for index in range(3):
    plain = data_gen.render_pair(5174, index, 2)
    shared = data_gen.render_pair(5174, index, 2, shared_material=0.5)
    d = plain["disparity"][0].numpy()
    colour = cv2.applyColorMap((255 * d / max(float(d.max()), 1e-6)).astype(np.uint8), cv2.COLORMAP_TURBO)
    rows.append(np.hstack([rgb(plain["left"]), rgb(shared["left"]), colour]))
out = sys.argv[1] if len(sys.argv) > 1 else "docs/experiments/shared_material_renders.png"
cv2.imwrite(out, cv2.resize(np.vstack(rows), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
print(out)
