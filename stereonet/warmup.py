"""Compile every compiled (numba) kernel once, so that no later call waits for the compiler.

    python -m stereonet.warmup [--quiet]

``make setup`` runs it. The kernels are ``cache=True``: numba writes the machine code beside the sources
(``__pycache__/*.nbi|nbc``) and every later process loads it instead of compiling (about 25 s on 2 cores for
the whole set). Each classical matcher runs once with its default options on a tiny pair, in float32 (what
``infer.py``/``eval.py`` use), plus the learned matchers' cost kernels, the shared occlusion fill, the weighted median
(sgm-refine's last step) and a tiny data_gen render. A kernel whose source changes is recompiled by numba on its next
call, as before.
"""

from __future__ import annotations

import argparse
import sys
import time


def warm_up(verbose: bool = True) -> list[tuple[str, float]]:
    """Run each compiled code path once; returns (name, seconds) per step."""
    import torch

    from stereonet import matchers

    g = torch.Generator().manual_seed(0)
    left = torch.rand(1, 3, 40, 72, generator=g)
    right = torch.roll(left, -3, dims=-1)
    steps: list[tuple[str, float]] = []

    def step(name, fn):
        t0 = time.perf_counter()
        fn()
        steps.append((name, time.perf_counter() - t0))
        if verbose:
            print(f"  {name}: {steps[-1][1]:.1f} s", file=sys.stderr, flush=True)

    for name in matchers.available():
        if matchers.spec(name).kind != "classical":
            continue
        step(name, lambda n=name: matchers.match(n, left, right, 16))

    # graphcut's unpruned moves (candidates=None) build the whole grid graph with another kernel
    step("graphcut unpruned", lambda: matchers.match("graphcut", left, right, 16, candidates=None))

    def learned_cost():  # the kernels of the Siamese matchers' cost (no weights needed)
        from stereonet.models.siamese import siamese_cost_volume

        feats = torch.nn.functional.normalize(torch.rand(2, 8, 40, 72, generator=g), dim=1)
        vol = siamese_cost_volume(feats[:1], feats[1:], 16, backend="numba")
        matchers.match("sgm", left, right, 16, extra_cost=(0.25, 18.0, vol))
        # the float32 aggregation: an unrounded mix (mix_step=None), or a mix outside the 16-bit path's range
        matchers.match("sgm", left, right, 16, extra_cost=(0.25, 18.0, vol), mix_step=None)

    step("learned cost", learned_cost)

    def fill():
        from stereonet.evaluation import apply_fill

        out = matchers.match("bm-sad", left, right, 16)
        apply_fill(out)

    step("fill", fill)

    def weighted_median():  # sgm-refine's last step (any map; float32 disparity and guide, the matcher's input)
        from stereonet.select.filters import weighted_median_filter

        out = matchers.match("sgm", left, right, 16)
        weighted_median_filter(out.disparity, left, valid=out.valid)

    step("weighted median", weighted_median)

    def render():
        import data_gen

        data_gen.SyntheticStereo(1, seed=0, difficulty=1, height=32, width=64, supersample=1)[0]

    step("data_gen", render)
    return steps


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m stereonet.warmup", description=__doc__.split("\n")[0])
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    if not args.quiet:
        print("stereonet: compiling the numba kernels once (cached for every later run)...", file=sys.stderr)
    warm_up(verbose=not args.quiet)
    if not args.quiet:
        print(f"stereonet: kernels ready in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
