"""Issue 15 item 3 (bp_phases.txt section 8): bp against opencv-sgbm on the real pairs, as make bench calls them
(reuse_freed_memory, PeakMemory's trim before every call), in one process per tree; run it alternately for two trees
(PYTHONPATH=TREE from a folder outside both). Per pair: the median of N calls of bp and of opencv-sgbm, their ratio
and bp's minor page faults per call.

    cd /tmp && PYTHONPATH=/path/to/tree python /path/to/docs/experiments/bp_lean_ab.py [N]
"""
import resource
import statistics
import sys
import time

import torch

from stereonet.data import load_dataset
from stereonet.evaluation import expand_data_specs
from stereonet.matchers import get_matcher
from stereonet.measure import PeakMemory, reuse_freed_memory


def faults() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def main(repeats: int) -> None:
    torch.set_num_threads(2)
    reuse_freed_memory()
    bp, sgbm = get_matcher("bp"), get_matcher("opencv-sgbm")
    pairs = []
    for spec in expand_data_specs("real"):  # ../shared/data (or STEREONET_SHARED_DATA)
        ds = load_dataset(spec)
        for i in range(len(ds)):
            item = ds[i]
            pairs.append((f"{spec.split(':')[0]}/{item['name']}", item["left"][None].float(), item["right"][None].float(),
                          int(item["max_disp"])))
    bp(pairs[0][1][..., :64, :64], pairs[0][2][..., :64, :64], 16)  # compile outside the timing
    ratios = []
    for name, left, right, max_disp in pairs:
        t_bp, t_sgbm, n_faults = [], [], []
        for _ in range(repeats):
            with torch.no_grad(), PeakMemory():
                f0, t0 = faults(), time.perf_counter()
                bp(left, right, max_disp)
                t_bp.append(time.perf_counter() - t0)
                n_faults.append(faults() - f0)
            with torch.no_grad(), PeakMemory():
                t0 = time.perf_counter()
                sgbm(left, right, max_disp)
                t_sgbm.append(time.perf_counter() - t0)
        ratio = statistics.median(a / b for a, b in zip(t_bp, t_sgbm))
        ratios.append(ratio)
        print(f"{name:28s} bp {statistics.median(t_bp):.3f} sgbm {statistics.median(t_sgbm):.3f} "
              f"ratio {ratio:.2f} faults {statistics.median(n_faults):.0f}")
    print(f"median ratio {statistics.median(ratios):.2f} worst {max(ratios):.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
