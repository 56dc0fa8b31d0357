"""Learned residual refinement of a classical disparity map (the ``sgm-refine`` matcher).

A small context network reads what the classical matcher knows and where it is unsure, and adds a residual:

* the left image (grey, standardised as every network here sees it),
* the photometric residual ``left - right warped by d`` (standardised grey): where it is large, ``d`` is wrong,
* the disparity ``d / max_disp`` (scale-free across image sizes and disparity ranges),
* the matcher's validity (1 where it passed its left-right and uniqueness checks, 0 where ``d`` was filled),
* the matcher's confidence in [0, 1] (SGM's cost margin).

Five 3x3 convolutions with dilations 1, 2, 4, 8, 1 (the context module of Yu & Koltun, 2016) give a ~37-pixel
support at full resolution, enough to carry a surface across an occlusion or a weakly textured patch; the last
convolution starts at zero, so an untrained network returns the classical map unchanged and training starts
from the classical matcher's accuracy, not from zero. The network is stateless (no loss in ``forward``).

``mode="select"`` replaces the regressed residual by a choice: each pixel keeps its own disparity or takes the one
of a neighbour at ``radii`` pixels in one of eight directions (PatchMatch-style propagation, scored by a learned
function of the shared context and of per-candidate evidence: the photometric residual of the candidate disparity,
the grey-level difference to the neighbour it comes from, the step from the pixel's own value, the neighbour's
validity and confidence). The output is always one of the classical map's values, so edges stay as sharp as the
classical map's: a regressed residual blends values across a discontinuity, and the first (residual) run made
every bad-τ worse while lowering EPE. The score head starts at zero: all candidates tie and the pixel's own value
(candidate 0) wins, so an untrained network again returns the classical map.

``bases`` names the matchers whose filled maps the network reads (``("sgm",)`` by default). With more than one
(``select`` only), every map contributes its own four input planes (residual, ``d / max_disp``, validity,
confidence) and its own candidates (its value at the pixel and at the same neighbours); each candidate also
carries its step from every map's value at the pixel and which map it comes from. Candidate 0 is the first map's
own value, so an untrained network returns the first map. Two matchers with different costs (census alone, a
learned cost) err in different places, so the best choice between them is far better than either; whether a
network learns that choice from synthetic pairs in a way that holds on real ones is what the experiment measures.
The network only reads the maps: the matcher (``sgm-refine``) and the training module run the named matchers.

``evidence="cross"`` (a choice between SGM-family matchers) also gives every candidate each matcher's opinion of it:
how far above its own best that matcher's aggregated cost lies at the candidate's disparity (:func:`cross_costs`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from stereonet.checks import StereoInputError
from stereonet.models.layers import standardize_image, warp_right

INPUT_CHANNELS = 5
"""left, photometric residual, d / max_disp, validity, confidence (one map; each further map adds 4 planes)."""

PLANES_PER_MAP = 4
"""photometric residual, d / max_disp, validity, confidence."""

CANDIDATE_CHANNELS = 6
"""per candidate: photometric residual, grey difference to its source pixel, step / max_disp, the source's validity
and confidence, its distance / the largest radius (one map; with M maps also the step from each other map's value
and the source map's index / (M - 1): M more)."""

BASES = ("sgm", "siamese-census-sgm", "siamese-sgm")
"""Matchers whose maps a RefineNet may read (``bases``)."""

MODES = ("residual", "select")
EVIDENCE = ("pixel", "census", "cross")
"""Per-candidate evidence of a ``select`` network: ``"pixel"`` the planes of :data:`CANDIDATE_CHANNELS`;
``"census"`` adds the windowed census distance of the candidate (:func:`census_distance`), one more plane;
``"cross"`` (a choice between matchers: two or more SGM-family bases, no radii) adds how much worse every base's own
aggregated cost finds the candidate than its best disparity (:func:`cross_costs`), one plane per base."""
CROSS_BASES = ("sgm", "siamese-census-sgm")
"""Bases whose aggregated SGM cost ``evidence="cross"`` reads (``keep_volume="fixed"``)."""
CROSS_NORM = 8 * 48.0
"""Cost units of one large-jump penalty on each of 8 paths (``sgm``'s P2 = 48 census bits): a candidate whose
aggregated cost exceeds the best by this much gets the cross-cost feature 0.5."""
CENSUS_RADIUS = 2
"""5x5 census (24 sign comparisons with the centre), averaged over a 5x5 box."""
DIRECTIONS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1))


def first_argmax(scores: torch.Tensor) -> torch.Tensor:
    """``scores.argmax(dim=1, keepdim=True)`` of a :math:`(B, K, H, W)` tensor, the same indices (ties and NaN as
    torch's: the first maximum, a NaN counts as the maximum), computed along a contiguous last axis: torch's CPU
    reduction over the short middle axis took 16 ms for K = 2 on a 450x375 pair (one thread), this ~1.3 ms."""
    return scores.movedim(1, -1).contiguous().argmax(-1).unsqueeze(1)


def cross_costs(aggregates: list[tuple[torch.Tensor, float]], disparity: torch.Tensor) -> torch.Tensor:
    """How much worse each base's aggregated cost finds each base's disparity than its own best, in ``[0, 1)``.

    ``aggregates``: per base, its aggregated SGM cost :math:`(B, D, H, W)` (any dtype, e.g. ``sgm``'s int16
    ``extras["aggregate_fixed"]``) and the scale of its units (``extras["aggregate_scale"]``: the volume holds
    ``scale * cost``); ``disparity`` :math:`(B, M, H, W)` the M bases' (filled) maps. Returns :math:`(B, M M, H, W)`,
    plane ``e * M + k`` = ``t / (1 + t)`` with ``t = (A_e(d_k) - min_d A_e) / (scale_e * CROSS_NORM)``, ``A_e(d)``
    the lower of base ``e``'s costs at the two integer disparities around ``d``: base ``e``'s opinion of base ``k``'s
    answer (0 where it is ``e``'s own best; ``e == k`` is above 0 where ``d_k`` was filled or moved by a filter). Every base's cost
    means the same on any scene (census bits for ``sgm``), so the evidence "the other matcher finds this answer
    costly" does not depend on the training renders' base rates."""
    maps = disparity.shape[1]
    if len(aggregates) != maps:
        raise StereoInputError(f"aggregates: expected one per map ({maps}), got {len(aggregates)}")
    planes = []
    for vol, scale in aggregates:
        d = vol.shape[1]
        best = vol.amin(1, keepdim=True).to(torch.float32)
        for k in range(maps):  # a sub-pixel value is as good as the better of the two disparities around it
            low = disparity[:, k:k + 1].floor().clamp(0, d - 1).long()
            at = torch.minimum(vol.gather(1, low), vol.gather(1, (low + 1).clamp(max=d - 1))).to(torch.float32)
            t = (at - best) / (float(scale) * CROSS_NORM)
            planes.append((t / (1.0 + t)).to(disparity.dtype))
    return torch.cat(planes, 1)


def candidate_offsets(radii: tuple[int, ...]) -> list[tuple[int, int]]:
    """(dy, dx) of the candidates: (0, 0) first, then eight directions at every radius."""
    return [(0, 0)] + [(dy * r, dx * r) for r in radii for dy, dx in DIRECTIONS]


def shift(x: torch.Tensor, dy: int, dx: int) -> torch.Tensor:
    """``out[..., y, x] = x[..., y + dy, x + dx]`` for :math:`(B, C, H, W)` ``x``, the border replicated (each
    pixel sees its neighbour's value)."""
    if dy == 0 and dx == 0:
        return x
    h, w = x.shape[-2:]
    top, left = max(-dy, 0), max(-dx, 0)
    xp = F.pad(x.float(), (left, max(dx, 0), top, max(dy, 0)), mode="replicate")
    return xp[..., top + dy:top + dy + h, left + dx:left + dx + w].to(x.dtype)


def census_distance(grey_l: torch.Tensor, warped_r: torch.Tensor, radius: int = CENSUS_RADIUS) -> torch.Tensor:
    """Windowed census distance in [0, 1] between the left image and the right image warped by a candidate map.

    At each pixel, the share of the ``(2r + 1)^2 - 1`` neighbours whose order against the centre (brighter or
    not) differs between ``grey_l`` and ``warped_r`` (both :math:`(B, 1, H, W)`), averaged over a
    ``(2r + 1)^2`` box. Unlike the grey residual it does not change under a monotonic change of brightness (a
    different exposure or gain in the right camera), and the window makes it a local matching cost rather than
    one pixel's difference: the evidence a classical matcher trusts, given here per candidate.
    """
    k = 2 * radius + 1
    pl = F.pad(grey_l, (radius,) * 4, mode="replicate")
    pr = F.pad(warped_r, (radius,) * 4, mode="replicate")
    h, w = grey_l.shape[-2:]
    differ = torch.zeros_like(grey_l)
    for dy in range(k):
        for dx in range(k):
            if dy == radius and dx == radius:
                continue
            bl = pl[..., dy:dy + h, dx:dx + w] > grey_l
            br = pr[..., dy:dy + h, dx:dx + w] > warped_r
            differ = differ + (bl != br).to(grey_l.dtype)
    differ = differ / float(k * k - 1)
    return F.avg_pool2d(F.pad(differ, (radius,) * 4, mode="replicate"), k, stride=1)


class RefineNet(nn.Module):
    """Refinement of a disparity map: a regressed residual (``mode="residual"``) or a choice among the map's own
    values at the pixel and its neighbours (``mode="select"``).

    Args:
        channels: width of every hidden layer.
        dilations: one 3x3 convolution per entry, with that dilation (zero-padded, same size).
        mode: "residual" or "select" (see the module docstring).
        radii: distances in pixels of the neighbours whose values are candidates (``select`` only; empty with
            two or more bases: the candidates are the maps' own values at the pixel, a choice between matchers).
        bases: the matchers whose maps it reads, in the order of the map channels (:data:`BASES`; more than one
            with ``select`` only).
        evidence: per-candidate evidence of a ``select`` network (:data:`EVIDENCE`): ``"census"`` adds each
            candidate's windowed census distance (:func:`census_distance`).
        filtered_bases: the bases (of ``bases``) whose maps the network reads after the image-guided weighted
            median (``sgm-refine``'s filter, :data:`stereonet.select.filters.WMF_RADIUS`); stored for the matcher
            and training, the network itself only reads the maps it is given.
    """

    def __init__(self, channels: int = 16, dilations: tuple[int, ...] | list[int] = (1, 2, 4, 8, 1),
                 mode: str = "residual", radii: tuple[int, ...] | list[int] = (1, 3, 9, 27),
                 bases: tuple[str, ...] | list[str] = ("sgm",), evidence: str = "pixel",
                 filtered_bases: tuple[str, ...] | list[str] = ()) -> None:
        super().__init__()
        if channels < 1:
            raise StereoInputError(f"channels: expected >= 1, got {channels}")
        if not dilations or any(int(d) < 1 for d in dilations):
            raise StereoInputError(f"dilations: expected a non-empty list of integers >= 1, got {list(dilations)}")
        if mode not in MODES:
            raise StereoInputError(f"mode: expected one of {', '.join(MODES)}, got {mode!r}")
        bases = tuple(bases)
        if mode == "select" and ((not radii and len(bases) < 2) or any(int(r) < 1 for r in radii)):
            raise StereoInputError(f"radii: expected a list of integers >= 1 (empty only with two or more bases), "
                                   f"got {list(radii)}")
        if not bases or any(b not in BASES for b in bases) or len(set(bases)) < len(bases):
            raise StereoInputError(f"bases: expected distinct names from {', '.join(BASES)}, got {list(bases)}")
        if evidence not in EVIDENCE or (evidence != "pixel" and mode != "select"):
            raise StereoInputError(f"evidence: expected one of {', '.join(EVIDENCE)} ('census', 'cross' with mode "
                                   f"'select'), got {evidence!r} with mode {mode!r}")
        if evidence == "cross" and (radii or len(bases) < 2 or any(b not in CROSS_BASES for b in bases)):
            raise StereoInputError(f"evidence: 'cross' is a choice between two or more of {', '.join(CROSS_BASES)} "
                                   f"(no radii), got bases {list(bases)} and radii {list(radii)}")
        if len(bases) > 1 and mode != "select":
            raise StereoInputError(f"bases: more than one map needs mode 'select', got mode {mode!r}")
        self.channels, self.dilations = int(channels), tuple(int(d) for d in dilations)
        filtered_bases = tuple(filtered_bases)
        if any(b not in bases for b in filtered_bases):
            raise StereoInputError(f"filtered_bases: expected names from bases ({', '.join(bases)}), "
                                   f"got {list(filtered_bases)}")
        self.mode, self.radii, self.bases, self.evidence = mode, tuple(int(r) for r in radii), bases, evidence
        self.filtered_bases = filtered_bases
        maps = len(bases)
        in_channels = INPUT_CHANNELS + PLANES_PER_MAP * (maps - 1)
        mods: list[nn.Module] = [nn.Conv2d(in_channels, self.channels, 3, padding=1), nn.ReLU(inplace=True)]
        for d in self.dilations:
            mods += [nn.Conv2d(self.channels, self.channels, 3, padding=d, dilation=d), nn.ReLU(inplace=True)]
        self.body = nn.Sequential(*mods)
        if mode == "residual":
            self.head = nn.Conv2d(self.channels, 1, 3, padding=1)
            nn.init.zeros_(self.head.weight)
            nn.init.zeros_(self.head.bias)
        else:  # score_k = w2 . relu(A ctx + B f_k + b): A ctx once per pixel, B f_k per candidate
            self.score_context = nn.Conv2d(self.channels, self.channels, 1)
            extra = (maps if maps > 1 else 0) + (1 if evidence == "census" else 0) + (maps if evidence == "cross" else 0)
            self.score_candidate = nn.Conv2d(CANDIDATE_CHANNELS + extra, self.channels, 1, bias=False)
            self.score_out = nn.Conv2d(self.channels, 1, 1)
            nn.init.zeros_(self.score_out.weight)
            nn.init.zeros_(self.score_out.bias)

    def inputs(self, left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor, valid: torch.Tensor,
               confidence: torch.Tensor, max_disp: float | torch.Tensor) -> torch.Tensor:
        """The input planes :math:`(B, 1 + 4 M, H, W)` of M maps :math:`(B, M, H, W)` (see the module
        docstring): the grey left image, then per map its residual, ``d / max_disp``, validity, confidence."""
        self._check_maps(disparity, valid, confidence)
        grey_l = standardize_image(left, grey=True)
        grey_r = standardize_image(right, grey=True)
        scale = _range(max_disp, disparity)
        planes = [grey_l]
        for m in range(disparity.shape[1]):
            d = disparity[:, m:m + 1]
            planes += [grey_l - warp_right(grey_r, d), d / scale, valid[:, m:m + 1].to(left.dtype),
                       confidence[:, m:m + 1].to(left.dtype)]
        return torch.cat(planes, 1)

    def _check_maps(self, disparity: torch.Tensor, valid: torch.Tensor, confidence: torch.Tensor) -> None:
        maps = len(self.bases)
        for name, t in (("disparity", disparity), ("valid", valid), ("confidence", confidence)):
            if t.dim() != 4 or t.shape[1] != maps:
                raise StereoInputError(f"{name}: expected (B, {maps}, H, W), one map per base "
                                       f"({', '.join(self.bases)}), got {tuple(t.shape)}")

    def forward(self, left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor, valid: torch.Tensor,
                confidence: torch.Tensor, max_disp: float | torch.Tensor,
                cross: torch.Tensor | None = None) -> torch.Tensor:
        """Refined disparity :math:`(B, 1, H, W)` >= 0 from images :math:`(B, C, H, W)` in [0, 1] and the
        classical matchers' filled disparities, validities and confidences :math:`(B, M, H, W)`, one map per
        base; ``max_disp`` the range the maps were searched in (a number, or one per item); ``cross``
        :math:`(B, M M, H, W)` the :func:`cross_costs` of an ``evidence="cross"`` network (else unused)."""
        if self.mode == "select":
            scores, candidates = self.scores(left, right, disparity, valid, confidence, max_disp, cross)
            return candidates.gather(1, first_argmax(scores))  # ties: the pixel's own value
        x = self.inputs(left, right, disparity, valid, confidence, max_disp)
        step = self.head(self.body(x))
        return F.relu(disparity + step)  # the residual in pixels: most corrections are a few pixels

    def scores(self, left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor, valid: torch.Tensor,
               confidence: torch.Tensor, max_disp: float | torch.Tensor,
               cross: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``select`` mode: candidate scores and candidate disparities, both :math:`(B, K, H, W)`, candidate 0
        the first map's own value; the first map's candidates in :func:`candidate_offsets`' order, then each
        further map's in the same order. ``cross``: as for :meth:`forward`."""
        if self.mode != "select":
            raise StereoInputError(f"mode: scores() needs mode 'select', this network has {self.mode!r}")
        if self.evidence == "cross":
            maps = len(self.bases)
            if cross is None or cross.dim() != 4 or cross.shape[1] != maps * maps or cross.shape[-2:] != disparity.shape[-2:]:
                got = None if cross is None else tuple(cross.shape)
                raise StereoInputError(f"cross: expected (B, {maps * maps}, H, W) cross costs (evidence 'cross'), "
                                       f"got {got}")
        x = self.inputs(left, right, disparity, valid, confidence, max_disp)
        grey_l, grey_r = x[:, :1], standardize_image(right, grey=True)
        ctx = self.score_context(self.body(x))
        scale, far = _range(max_disp, disparity), float(max(self.radii, default=1))
        maps = disparity.shape[1]
        valid_f, conf = valid.to(left.dtype), confidence.to(left.dtype)
        scores, candidates = [], []
        for m in range(maps):
            own = disparity[:, m:m + 1]
            for dy, dx in candidate_offsets(self.radii):
                cand = shift(own, dy, dx)
                warped = warp_right(grey_r, cand)
                planes = [(grey_l - warped).abs(), (grey_l - shift(grey_l, dy, dx)).abs(),
                          (cand - disparity[:, :1]) / scale, shift(valid_f[:, m:m + 1], dy, dx),
                          shift(conf[:, m:m + 1], dy, dx), torch.full_like(cand, max(abs(dy), abs(dx)) / far)]
                if maps > 1:  # the step from every other map's value, and which map it comes from
                    planes += [(cand - disparity[:, k:k + 1]) / scale for k in range(1, maps)]
                    planes.append(torch.full_like(cand, m / (maps - 1)))
                if self.evidence == "census":
                    planes.append(census_distance(grey_l, warped))
                if self.evidence == "cross":  # every base's opinion of this candidate (own value: offset 0)
                    planes += [cross[:, e * maps + m:e * maps + m + 1].to(cand.dtype) for e in range(maps)]
                scores.append(self.score_out(F.relu(ctx + self.score_candidate(torch.cat(planes, 1)))))
                candidates.append(cand)
        return torch.cat(scores, 1), torch.cat(candidates, 1)


def _range(max_disp: float | torch.Tensor, like: torch.Tensor) -> float | torch.Tensor:
    """``max_disp`` (one number, or one per batch item :math:`(B,)`) as a divisor >= 1 broadcastable to ``like``."""
    if isinstance(max_disp, torch.Tensor):
        return max_disp.to(like).clamp(min=1.0).view(-1, 1, 1, 1)
    return max(float(max_disp), 1.0)
