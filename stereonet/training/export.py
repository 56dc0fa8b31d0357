"""Export a training checkpoint to a slim weights file, and plot training curves.

    python -m stereonet.training.export weights CKPT OUT.pt [--notes TEXT]
    python -m stereonet.training.export curves OUT.png NAME=LOGDIR [NAME=LOGDIR ...] [--tag val/epe]

``weights`` keeps only the network's tensors, its name and config (what the registry needs), in float32.
``curves`` reads TensorBoard event files (every ``version_*`` under LOGDIR, in time order, so resumed runs
continue the curve) and plots ``tag`` against wall-clock minutes of training.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from stereonet.io.atomic import atomic_path
from stereonet.models.weights import load_weights, save_weights


def export_weights(ckpt: str | Path, out: str | Path, notes: str | None = None) -> dict:
    """Write the slim weights of a Lightning checkpoint (or re-save a slim file); returns its info."""
    net, info = load_weights(ckpt)
    extra = {"notes": notes} if notes else {}
    if info.get("trained_on"):  # the weights files whose outputs the network was trained on (sha256)
        extra["trained_on"] = dict(info["trained_on"])
    save_weights(out, info["model"], dict(info["config"]), net, **extra)
    return info


def read_curve(logdir: str | Path, tag: str) -> list[tuple[float, float, int]]:
    """(minutes since the first event, value, step) of ``tag`` over all event files under ``logdir``.

    Time spent between runs (a kill and a resume) is not counted: each run's minutes continue from the
    previous run's last event.
    """
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    points: list[tuple[float, float, int]] = []
    offset = 0.0
    for events in sorted(Path(logdir).rglob("events.out.tfevents.*"), key=lambda p: p.stat().st_mtime):
        acc = EventAccumulator(str(events), size_guidance={"scalars": 0})
        acc.Reload()
        if tag not in acc.Tags().get("scalars", []):
            continue
        scalars = acc.Scalars(tag)
        wall_tags = acc.Scalars("train/loss") if "train/loss" in acc.Tags()["scalars"] else scalars
        start = min(s.wall_time for s in wall_tags + scalars)
        for s in scalars:
            points.append((offset + (s.wall_time - start) / 60.0, float(s.value), int(s.step)))
        offset = points[-1][0] if points else offset
    return points


def plot_curves(out: str | Path, runs: dict[str, str | Path], tag: str = "val/epe") -> dict[str, list]:
    """Plot ``tag`` vs minutes for each named run into ``out`` (PNG, written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = {name: read_curve(logdir, tag) for name, logdir in runs.items()}
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, pts in curves.items():
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3, label=name)
    ax.set_xlabel("training time on the shared 2-core CPU [minutes]")
    ax.set_ylabel(tag + " (fixed data_gen validation set)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return curves


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    w = sub.add_parser("weights", help="checkpoint -> slim weights file")
    w.add_argument("ckpt")
    w.add_argument("out")
    w.add_argument("--notes", default=None)
    c = sub.add_parser("curves", help="plot a TensorBoard scalar against minutes")
    c.add_argument("out")
    c.add_argument("runs", nargs="+", help="NAME=LOGDIR")
    c.add_argument("--tag", default="val/epe")
    args = parser.parse_args(argv)
    if args.command == "weights":
        from stereonet.checks import StereoInputError
        from stereonet.cli.common import fail

        out = Path(args.out)
        if out.is_dir() or not out.parent.is_dir():
            return fail("stereonet.training.export", f"out: expected a file path in an existing folder, got {out}")
        try:
            export_weights(args.ckpt, out, args.notes)
        except (StereoInputError, FileNotFoundError) as e:  # bad input: one line, exit 2, nothing written
            return fail("stereonet.training.export", e)
        return 0
    runs = {}
    for spec in args.runs:
        if "=" not in spec:
            parser.error(f"runs: expected NAME=LOGDIR, got {spec!r}")
        name, logdir = spec.split("=", 1)
        runs[name] = logdir
    plot_curves(args.out, runs, args.tag)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
