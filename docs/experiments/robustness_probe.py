"""Issue 14, thirty-third session: how the matchers degrade when the right view is imperfect in the ways real rigs and
phone pairs are (a diagnostic on data_gen renders, no decision): a vertical offset of the right image (residual
rectification error; sub-pixel by bilinear resampling), a lower exposure of the right camera (gain), a different
response curve (gamma), and sensor noise on both views. The ground truth stays the left view's (a vertical offset makes
every match 0.5-1 px off the scanline, which is what a matcher must tolerate, not a change of the disparity).
Prints the mean bad-2 (eval.py's metrics after the shared fill) of each method under each perturbation.
Run: python docs/experiments/robustness_probe.py "sgm,sgm:binomial,sgm-refine,opencv-sgbm" "val2ai" [align|jpeg]
(METHOD:PREFILTER runs the method with that census pre-filter, stereonet.cost.prefilter; "align": the vertical offsets
with and without stereonet.geometry.align.auto_align before matching; "camera": blur, vignetting, noise and JPEG)"""
import statistics
import sys

import torch
import torch.nn.functional as F

sys.path.insert(0, "docs/experiments")
from val_sets import expand, items  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.evaluation import apply_fill, pair_metrics  # noqa: E402


def shifted(img: torch.Tensor, dy: float) -> torch.Tensor:
    """``img`` (B, C, H, W) moved down by ``dy`` px (bilinear; border replicated)."""
    _, _, h, w = img.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=img.dtype), torch.arange(w, dtype=img.dtype), indexing="ij")
    grid = torch.stack([(2 * xs + 1) / w - 1, (2 * (ys - dy) + 1) / h - 1], -1)[None]
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=False)


def jpeg(img: torch.Tensor, quality: int) -> torch.Tensor:
    """``img`` (1, C, H, W) through JPEG at ``quality`` (OpenCV), as a phone or a web upload stores it."""
    import cv2
    import numpy as np

    a = (img[0].permute(1, 2, 0).numpy() * 255).round().clip(0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", a[..., ::-1] if a.shape[2] == 3 else a, [cv2.IMWRITE_JPEG_QUALITY, quality])
    b = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    b = b[..., ::-1] if b.ndim == 3 else b[..., None]
    return torch.from_numpy(np.ascontiguousarray(b)).permute(2, 0, 1)[None].to(img.dtype) / 255.0


def tilted(img: torch.Tensor, dy_at_right_edge: float) -> torch.Tensor:
    """``img`` moved down by ``dy_at_right_edge * x / (W - 1)`` px (a small relative rotation of the views)."""
    _, _, h, w = img.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=img.dtype), torch.arange(w, dtype=img.dtype), indexing="ij")
    grid = torch.stack([(2 * xs + 1) / w - 1, (2 * (ys - dy_at_right_edge * xs / (w - 1)) + 1) / h - 1], -1)[None]
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=False)


def aligned(perturb):
    """The perturbation, then stereonet.geometry.align.auto_align on the result (what infer.py does)."""
    from stereonet.geometry.align import auto_align

    def run(left, right, g):
        left, right = perturb(left, right, g)
        return left, auto_align(left, right)[0]
    return run


PERTURBATIONS = {
    "clean": lambda left, right, g: (left, right),
    "right down 0.5 px": lambda left, right, g: (left, shifted(right, 0.5)),
    "right down 1 px": lambda left, right, g: (left, shifted(right, 1.0)),
    "right gain 0.6": lambda left, right, g: (left, right * 0.6),
    "right gamma 1.6": lambda left, right, g: (left, right.clamp(0, 1) ** 1.6),
    "noise 0.03 both": lambda left, right, g: ((left + 0.03 * torch.randn(left.shape, generator=g)).clamp(0, 1),
                                                (right + 0.03 * torch.randn(right.shape, generator=g)).clamp(0, 1)),
}
if len(sys.argv) > 3 and sys.argv[3] == "jpeg":  # compression as phones and web uploads store photos
    PERTURBATIONS = {"clean": PERTURBATIONS["clean"],
                     "jpeg 90 both": lambda left, right, g: (jpeg(left, 90), jpeg(right, 90)),
                     "jpeg 75 both": lambda left, right, g: (jpeg(left, 75), jpeg(right, 75)),
                     "jpeg 50 both": lambda left, right, g: (jpeg(left, 50), jpeg(right, 50))}
if len(sys.argv) > 3 and sys.argv[3] == "align":  # the offsets with and without auto_align (thirty-third session)
    PERTURBATIONS = {
        "clean": PERTURBATIONS["clean"],
        "clean, aligned": aligned(PERTURBATIONS["clean"]),
        "right down 0.5 px": PERTURBATIONS["right down 0.5 px"],
        "right down 0.5 px, aligned": aligned(PERTURBATIONS["right down 0.5 px"]),
        "right down 1 px": PERTURBATIONS["right down 1 px"],
        "right down 1 px, aligned": aligned(PERTURBATIONS["right down 1 px"]),
        "right tilted 0-1 px": lambda left, right, g: (left, tilted(right, 1.0)),
        "right tilted 0-1 px, aligned": aligned(lambda left, right, g: (left, tilted(right, 1.0))),
    }

def blurred(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """``img`` (1, C, H, W) under a Gaussian blur of ``sigma`` px (optics, demosaicing, a slightly wrong focus)."""
    r = max(1, int(3 * sigma + 0.5))
    x = torch.arange(-r, r + 1, dtype=img.dtype)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    c = img.shape[1]
    out = F.conv2d(F.pad(img, (r, r, 0, 0), mode="replicate"), k.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(F.pad(out, (0, 0, r, r), mode="replicate"), k.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)


def vignetted(img: torch.Tensor, corner: float) -> torch.Tensor:
    """``img`` darkened radially (cos^4-like falloff, ``corner`` of the centre's brightness at the corners)."""
    _, _, h, w = img.shape
    ys, xs = torch.meshgrid(torch.linspace(-1, 1, h, dtype=img.dtype), torch.linspace(-1, 1, w, dtype=img.dtype),
                            indexing="ij")
    r2 = (xs ** 2 + ys ** 2) / 2.0  # 1 at the corners
    return img * (1.0 - (1.0 - corner) * r2)


if len(sys.argv) > 3 and sys.argv[3] == "camera":  # what a camera does to both views (forty-second session)
    PERTURBATIONS = {
        "clean": PERTURBATIONS["clean"],
        "blur 1 px both": lambda left, right, g: (blurred(left, 1.0), blurred(right, 1.0)),
        "right blur 1 px": lambda left, right, g: (left, blurred(right, 1.0)),
        "right vignetting 0.6": lambda left, right, g: (left, vignetted(right, 0.6)),
        "noise 0.03 both": PERTURBATIONS["noise 0.03 both"],
        "jpeg 75 both": lambda left, right, g: (jpeg(left, 75), jpeg(right, 75)),
    }


def variant(entry: str) -> str:
    """``METHOD`` (or ``LABEL=METHOD@CHECKPOINT``), or ``METHOD:PREFILTER``: the census pre-filter option set."""
    if ":" not in entry:
        return matchers.register_checkpoint_variant(entry)
    method, prefilter = entry.split(":")
    fn = matchers.get_matcher(method, prefilter=prefilter)
    matchers.register(entry, kind="learned", description=f"{method}, prefilter {prefilter}")(lambda a, b, d: fn(a, b, d))
    return entry


methods = [variant(a) for a in sys.argv[1].split(",")]
specs = expand(sys.argv[2])
rows = {}
for _spec, item in items(specs):
    gen = torch.Generator().manual_seed(0)
    for pname, perturb in PERTURBATIONS.items():
        left, right = perturb(item["left"][None], item["right"][None], gen)
        for m in methods:
            with torch.no_grad():
                out = apply_fill(matchers.match(m, left, right, int(item["max_disp"])))
            rows.setdefault((m, pname), []).append(pair_metrics(out, item)["bad2"])
names = list(PERTURBATIONS)
print("| method | " + " | ".join(names) + " |")
print("|---" * (len(names) + 1) + "|")
for m in methods:
    print(f"| {m} | " + " | ".join(f"{statistics.fmean(rows[(m, p)]):.2f}" for p in names) + " |")
