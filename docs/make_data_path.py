"""Draw docs/readme/data_path.png: the data path of a stereo pair through stereonet (README, "How it fits
together").   python docs/make_data_path.py"""
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

STAGES = [
    ("images", "io.read_image\ndata.load_dataset\ndata_gen"),
    ("rectify", "geometry\n(kornia: F, E, pose,\nrectification)"),
    ("cost", "cost/\nSAD ... census,\nSiamese features"),
    ("aggregate", "aggregate/\nSGM, DP, BP,\ngraph cuts, soft"),
    ("select", "select/\nWTA, subpixel, LR,\nfill, filters"),
    ("StereoOutput", "disparity, valid,\nconfidence /\nuncertainty"),
    ("3-D", "geometry.depth\ndepth, points\nio: PFM, PNG, PLY"),
]


OUT = Path(__file__).resolve().parent / "readme" / "data_path.png"


def main(out: Path = OUT) -> None:
    fig = Figure(figsize=(13, 3.3), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(0, 14)
    ax.set_ylim(0, 4.2)
    ax.axis("off")
    xs = [0.3 + 1.95 * i for i in range(len(STAGES))]
    for x, (title, body) in zip(xs, STAGES):
        ax.add_patch(FancyBboxPatch((x, 1.5), 1.6, 1.9, boxstyle="round,pad=0.05", fc="#eef3fb", ec="#3b5b92"))
        ax.text(x + 0.8, 3.1, title, ha="center", va="center", fontsize=11, weight="bold")
        ax.text(x + 0.8, 2.2, body, ha="center", va="center", fontsize=8.2)
    for a, b in zip(xs, xs[1:]):
        ax.add_patch(FancyArrowPatch((a + 1.68, 2.45), (b - 0.08, 2.45), arrowstyle="-|>", mutation_scale=14))
    # end-to-end networks replace cost -> select
    x0, x1 = xs[2], xs[4] + 1.6
    ax.add_patch(FancyBboxPatch((x0, 0.35), x1 - x0, 0.7, boxstyle="round,pad=0.05", fc="#fbefe6", ec="#a0522d"))
    ax.text((x0 + x1) / 2, 0.7, "models/: DispNet, SMD (end to end) replace cost -> select\n"
            "matchers/: one registry, name -> path; kernels/: numba CPU kernels", ha="center", va="center", fontsize=8.6)
    ax.text(7.0, 3.95, "one pair through stereonet: infer.py runs the whole path, eval.py scores StereoOutput, "
            "train.py fits models/ on data_gen", ha="center", fontsize=9.5, style="italic")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)


if __name__ == "__main__":
    main()
