"""Disparity space image (DSI) of one scanline, for teaching plots.

The DSI of row ``y`` is the ``D x W`` slice ``cost[b, :, y, :]`` of a cost volume: column ``x`` holds the
costs of every disparity for the left pixel ``(y, x)``. A disparity map of that row is a path through it;
WTA picks each column's minimum independently, DP / SGM trade the costs off against smoothness.
"""

from __future__ import annotations

import os

import torch

from stereonet.checks import StereoInputError, check_cost_volume, check_shape


def dsi_scanline(cost: torch.Tensor, row: int, batch: int = 0,
                 path: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The DSI of one row and a path through it.

    Args:
        cost: :math:`(B, D, H, W)` costs (lower = better).
        row: image row ``0 <= row < H``.
        batch: batch index.
        path: optional disparity of that row, :math:`(W,)` or a full map :math:`(B, 1, H, W)` (e.g. from
            DP or SGM); default: the WTA path (argmin over D per column, ties to the smallest d).

    Returns:
        ``(dsi, path)``: :math:`(D, W)` costs and :math:`(W,)` float disparities.
    """
    check_cost_volume(cost)
    b, n, h, w = cost.shape
    if not (isinstance(row, int) and 0 <= row < h):
        raise StereoInputError(f"row: expected an integer in [0, {h}), got {row!r}")
    if not (isinstance(batch, int) and 0 <= batch < b):
        raise StereoInputError(f"batch: expected an integer in [0, {b}), got {batch!r}")
    dsi = cost[batch, :, row, :].detach()  # DxW
    if path is None:
        return dsi, dsi.argmin(dim=0).to(dsi.dtype)
    if path.dim() == 4:
        check_shape(path, [str(b), "1", str(h), str(w)], "path")
        path = path[batch, 0, row]
    check_shape(path, [str(w)], "path")
    return dsi, path.detach().to(dsi.dtype)


def plot_dsi(dsi: torch.Tensor, paths: dict[str, torch.Tensor] | None = None, title: str = "DSI",
             out: str | os.PathLike | None = None):
    """Plot a DSI (x horizontal, disparity vertical) with paths overlaid; optionally save it as PNG.

    Uses matplotlib's object API with the Agg canvas (no global backend change, no display needed).

    Args:
        dsi: :math:`(D, W)` costs.
        paths: ``{label: (W,) disparities}`` drawn over the image.
        title: figure title.
        out: PNG path, written atomically (:mod:`stereonet.io.atomic`).

    Returns:
        the ``matplotlib.figure.Figure``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    check_shape(dsi, ["D", "W"], "dsi")
    n, w = dsi.shape
    fig = Figure(figsize=(max(4.0, w / 60), max(2.5, n / 25)), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    im = ax.imshow(dsi.float().cpu().numpy(), origin="lower", aspect="auto", cmap="viridis", interpolation="nearest")
    for label, p in (paths or {}).items():
        check_shape(p, [str(w)], f"paths[{label!r}]")
        ax.plot(range(w), p.float().cpu().numpy(), linewidth=1.0, label=label)
    if paths:
        ax.legend(loc="upper right", fontsize=7)
    ax.set_xlabel("x (left image column)")
    ax.set_ylabel("disparity d")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, label="cost")
    fig.tight_layout()
    if out is not None:
        from stereonet.io.atomic import atomic_path

        with atomic_path(out, suffix=".png") as tmp:
            fig.savefig(tmp, format="png")
    return fig
