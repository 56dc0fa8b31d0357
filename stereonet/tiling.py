"""Matching under a memory budget: horizontal strips with overlapping margins, stitched back.

Every matcher's memory grows with ``W x H x D`` (cost volumes, path accumulators, network activations), so
a large pair can exceed the machine. :func:`match_with_budget` runs a matcher on strips of whole rows whose
size fits ``budget_mib``: each strip is extended by ``overlap`` rows above and below (context for window
costs, SGM's vertical and diagonal paths and a network's receptive field) and only its core rows are kept.
The bytes one row needs are *measured*, not guessed: the matcher runs once on a probe strip under
:class:`stereonet.measure.PeakMemory`, and the strip height follows from the budget with a safety factor, so
the rule holds for every method, classical or learned. A budget too small for one strip (the overlap plus a
minimum core) is a one-line :class:`~stereonet.checks.StereoInputError` naming the budget.

With enough overlap the stitched map equals the untiled one except near the seams of a long-range method
(SGM's 8 paths see the whole image); the tests and ``docs/experiments`` measure the difference.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields, replace

import torch

from stereonet.checks import StereoInputError
from stereonet.measure import PeakMemory, release_free_memory
from stereonet.types import StereoOutput

# fits an 8 GB laptop beside the rest of the process (and a browser); measured with scripts/bench_large.py, sgm on
# a 6 MP / 256-disparity pair is *faster* in 5 strips under 2048 MiB (1.24x SGBM, peak 1.4 GiB) than in 2 under
# 4096 (1.37x, 2.8 GiB): smaller strips stay in cache, which pays for the overlap rows
DEFAULT_BUDGET_MIB = 2048
DEFAULT_OVERLAP = 48
MIN_CORE = 16
PROBE_ROWS = 32
SAFETY = 0.7  # share of the budget the planned strips may use (the probe's measurement is a lower bound)
# Bytes per (pixel x disparity) that no matcher here exceeds (sgm peaks at ~4 on Cones since its 16-bit
# aggregation, ~14 before; the float32 energy matchers and the networks stay below 32 too):
# a pair whose W x H x (D + 1) times this fits the budget runs whole, without a probe.
UPPER_BYTES_PER_CELL = 32


class MemoryBudgetError(StereoInputError):
    """The budget cannot hold one strip: bad input (the budget), not a failure of the method."""


def _rows_of(out: StereoOutput, top: int, bottom: int, scale: float = 1.0) -> StereoOutput:
    """Rows ``[top, bottom)`` of the input strip in every per-pixel field (the cost volume and extras are dropped),
    as copies (a view would keep the whole strip's storage, overlap rows included, until the end). ``scale``: the
    output grid's rows per input row (``--output-scale``); ``top * scale`` must be whole (:func:`_scale_step`)."""
    changes = {}
    rows = out.disparity.shape[-2]
    t, b = round(top * scale), min(rows, round(bottom * scale))
    for f in fields(out):
        value = getattr(out, f.name)
        if f.name == "cost_volume":
            changes[f.name] = None
        elif f.name == "extras":
            changes[f.name] = {}
        elif isinstance(value, torch.Tensor):
            changes[f.name] = value[..., t:b, :].clone()
    return replace(out, **changes)


def _scale_step(scale: float, limit: int = 64) -> int | None:
    """The fewest input rows ``q`` (<= ``limit``) that are a whole number of output rows at ``scale``: strips that
    start on multiples of ``q`` put their output rows on the whole pair's output grid. None if there is none."""
    for q in range(1, limit + 1):
        if abs(q * scale - round(q * scale)) < 1e-9:
            return q
    return None


class _CudaPeak:
    """:class:`~stereonet.measure.PeakMemory`'s interface for a CUDA device: peak allocated bytes in the block."""

    def __init__(self, device: torch.device) -> None:
        self.device, self.peak_mib = device, 0.0

    def __enter__(self) -> _CudaPeak:
        torch.cuda.synchronize(self.device)
        torch.cuda.reset_peak_memory_stats(self.device)
        self._base = torch.cuda.memory_allocated(self.device)
        return self

    def __exit__(self, *exc) -> None:
        torch.cuda.synchronize(self.device)
        self.peak_mib = max(0.0, (torch.cuda.max_memory_allocated(self.device) - self._base) / 2 ** 20)


def _concat(parts: list[StereoOutput]) -> StereoOutput:
    first = parts[0]
    changes = {}
    for f in fields(first):
        value = getattr(first, f.name)
        if isinstance(value, torch.Tensor):
            changes[f.name] = torch.cat([getattr(p, f.name) for p in parts], dim=-2)
    return replace(first, **changes)


def plan_strips(height: int, rows_per_strip: int, overlap: int, step: int = 1) -> list[tuple[int, int, int, int]]:
    """``(y0, y1, core_top, core_bottom)`` per strip: the strip's rows ``[y0, y1)`` and, inside it, the core
    rows kept; cores tile ``[0, height)`` exactly. ``step``: cores, overlaps and so every ``y0`` are multiples
    of it (the overlap rounded up, the core down, at least one step)."""
    overlap = -(-overlap // step) * step
    core = max(step, (rows_per_strip - 2 * overlap) // step * step)
    out = []
    for top in range(0, height, core):
        bottom = min(height, top + core)
        y0, y1 = max(0, top - overlap), min(height, bottom + overlap)
        out.append((y0, y1, top - y0, bottom - y0))
    return out


def match_with_budget(fn: Callable[..., StereoOutput], left: torch.Tensor, right: torch.Tensor, max_disp: int,
                      budget_mib: float = DEFAULT_BUDGET_MIB, overlap: int = DEFAULT_OVERLAP,
                      info: dict | None = None, rows_per_strip: int | None = None,
                      output_scale: float = 1.0) -> StereoOutput:
    """``fn(left, right, max_disp)`` within ``budget_mib`` MiB of extra memory, in strips when needed.

    ``info`` (optional) receives ``strips``, ``rows_per_strip``, ``bytes_per_row`` and ``overlap``.
    ``rows_per_strip`` fixes the strip height instead of deriving it from the budget (tests, experiments).
    ``output_scale``: ``fn`` answers on a grid this many times the input's (SMD's ``upsample``): strips then start
    on rows whose output row is whole, so their rows land on the whole pair's output grid; a scale with no such
    row within 64 is a one-line error when strips are needed. On a CUDA tensor the probe measures the device's
    allocated memory instead of the process's.
    """
    info = {} if info is None else info
    h = int(left.shape[-2])
    step = 1 if output_scale == 1 else _scale_step(output_scale)
    if rows_per_strip is None:
        if not budget_mib > 0:
            raise StereoInputError(f"--memory-budget: expected a positive number of MiB, got {budget_mib}")
        info.update(overlap=overlap)
        cells = left.shape[-1] * h * (max_disp + 1) * max(1.0, output_scale) ** 2
        if cells * UPPER_BYTES_PER_CELL <= budget_mib * 2**20:
            info.update(strips=1, rows_per_strip=h)
            return fn(left, right, max_disp)
        probe_rows = min(h, PROBE_ROWS + 2 * overlap)
        with (_CudaPeak(left.device) if left.is_cuda else PeakMemory()) as mem:
            probe = fn(left[..., :probe_rows, :], right[..., :probe_rows, :], max_disp)
        per_row = max(mem.peak_mib, 1e-3) * 2**20 / probe_rows
        rows_per_strip = int(SAFETY * budget_mib * 2**20 / per_row)
        info.update(bytes_per_row=int(per_row))
        if rows_per_strip >= h:  # the whole pair fits
            info.update(strips=1, rows_per_strip=h)
            return probe if probe_rows == h else fn(left, right, max_disp)
        if rows_per_strip - 2 * overlap < MIN_CORE:
            need = (2 * overlap + MIN_CORE) * per_row / SAFETY / 2**20
            raise MemoryBudgetError(f"--memory-budget: {budget_mib:g} MiB is too small for one strip of this "
                                    f"pair ({left.shape[-1]} px wide, {max_disp} disparities): needs at least "
                                    f"{need:.0f} MiB")
    if step is None:
        raise StereoInputError(f"--output-scale: {output_scale:g} has no whole output row within 64 input rows, so "
                               f"this pair cannot run in strips; pass a simpler scale (e.g. 1.5, 2) or a larger "
                               f"--memory-budget")
    strips = plan_strips(h, int(rows_per_strip), overlap, step)
    info.update(strips=len(strips), rows_per_strip=int(rows_per_strip), overlap=overlap)
    parts = []
    for y0, y1, top, bottom in strips:
        release_free_memory()  # what the last strip freed goes back (a heap that keeps freed memory: measure)
        parts.append(_rows_of(fn(left[..., y0:y1, :], right[..., y0:y1, :], max_disp), top, bottom, output_scale))
    return _concat(parts)
