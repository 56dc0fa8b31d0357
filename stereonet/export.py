"""ONNX export of the learned matchers.

    python -m stereonet.export onnx --method NAME -o FILE.onnx [--checkpoint CKPT] [--height H --width W]
                                    [--max-disp D] [--overwrite]

What is exported is the *network* of the matcher (the graphs of :mod:`stereonet.models.graphs`):
``siamese``, ``siamese-sgm`` and ``siamese-census-sgm`` share the Siamese feature tower (cost volume, SGM, WTA,
LR check and the rest stay classical and run on the ONNX features); ``dispnet`` exports the whole DispNet from
the padded image pair to its disparity, ``smd`` the DispNet backbone with its mixture head, from the padded
pair and a query grid to the bimodal mixture (``mu1, mu2, b1, b2, pi``), so any output scale works. Batch,
height and width are dynamic axes; H x W is the size the graph is traced at and verified on (the bundled
Middlebury *cones* pair, resized), and the pair's full 450 x 375 is verified too; a graph further than
:data:`stereonet.models.graphs.VERIFY_TOLERANCE` from torch is not written. ``--max-disp`` is the disparity
range of the end-to-end check of ``--method`` itself (torch against onnxruntime on the resized pair, from the
written file), printed with the rest.

The exporter is torch's TorchScript-based one (``dynamo=False``, see
:func:`stereonet.models.graphs.trace_to_onnx` for why), so ``onnxscript`` is not needed.

The file's metadata (``stereonet.*`` properties) carries what the runtime needs: format, network, the methods
that use it, the ``max_disp`` the network was trained for, stride and smallest width, input normalisation,
config, weights file and the verified difference. ``--backend onnx`` of the learned matchers (and of
``infer.py``) runs it with ``onnx_model=FILE``. Written atomically; bad input is one line and exit code 2, with
nothing written.
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from stereonet.checks import StereoInputError

PROG = "python -m stereonet.export"
DEFAULT_SIZE = (96, 128)  # (height, width): traced and verified on; the graph takes any size
DEFAULT_CHECK_MAX_DISP = 32


@dataclass
class ExportReport:
    """What :func:`export_onnx` wrote and how close onnxruntime came to torch."""

    path: Path
    network: str
    methods: list[str]
    graph_difference: float  # largest output difference of the graph on the verification pairs
    disparity_difference: float | None  # the method end to end: max |d_torch - d_onnx| over pixels valid in both
    valid_agree: bool | None  # the method's valid masks are equal


def learned_network(method: str) -> str:
    """The network ``method`` runs ("siamese", "dispnet", "smd"); StereoInputError naming ``method`` otherwise."""
    from stereonet import matchers
    from stereonet.matchers.learned import NETWORK_OF

    spec = matchers.spec(method)  # unknown names: the registry's error lists the valid ones
    if spec.kind != "learned" or method not in NETWORK_OF:
        learned = ", ".join(n for n in matchers.available("learned") if n in NETWORK_OF)
        raise StereoInputError(f"method: {method!r} is a {spec.kind} matcher with no network to export; "
                               f"learned matchers: {learned}")
    return NETWORK_OF[method]


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_writable(path: str | os.PathLike, overwrite: bool = False) -> Path:
    """``path`` as a file that can be written (its folder exists or can be made); errors name ``out``."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"out: {path} is a folder, expected a file name like model.onnx")
    if path.exists() and not overwrite:
        raise FileExistsError(f"out: {path} already exists (pass --overwrite to replace it)")
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise NotADirectoryError(f"out: cannot write {path}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"out: cannot write {path}: {parent} is not writable")
    return path


def export_onnx(method: str, out: str | os.PathLike, checkpoint: str | os.PathLike | None = None,
                height: int = DEFAULT_SIZE[0], width: int = DEFAULT_SIZE[1],
                max_disp: int | None = DEFAULT_CHECK_MAX_DISP, overwrite: bool = False) -> ExportReport:
    """Export the network of learned matcher ``method`` to the ONNX file ``out`` (see the module doc).

    Args:
        method: a registered learned matcher.
        out: the ``.onnx`` file, written atomically (only after the graph has been verified).
        checkpoint: weights (slim ``.pt`` or Lightning ``.ckpt``); default the shipped ones.
        height, width: size the graph is traced and verified at (it accepts any size afterwards).
        max_disp: disparity range of the end-to-end check of ``method``; None skips that check.
    Raises:
        StereoInputError / FileNotFoundError / ... naming the argument; RuntimeError if the export does not
        reproduce torch (nothing is written then).
    """
    from stereonet import matchers
    from stereonet.io.atomic import atomic_path
    from stereonet.matchers.learned import methods_of
    from stereonet.models.graphs import export_graph, verification_pair
    from stereonet.models.weights import default_weights_path, load_weights

    network = learned_network(method)
    out = check_writable(out, overwrite)
    if max_disp is not None and not 0 < max_disp < width:
        raise StereoInputError(f"max_disp: expected 0 < max_disp < width ({width}), got {max_disp}")
    weights = Path(checkpoint) if checkpoint is not None else default_weights_path(network)
    net, info = load_weights(weights, network)  # FileNotFoundError / StereoInputError naming the checkpoint
    exported = export_graph(network, net, dict(info["config"]), methods_of(network), height, width,
                            method=method, weights=weights.name, weights_sha256=_sha256(weights),
                            torch_version=torch.__version__)
    disparity_difference = valid_agree = None
    with atomic_path(out) as tmp:
        tmp.write_bytes(exported.model)
        if max_disp is not None:  # the method end to end, on the file as written
            left, right = verification_pair(height, width)
            options = {} if checkpoint is None else {"checkpoint": str(checkpoint)}
            ref = matchers.match(method, left, right, max_disp, **options)
            got = matchers.match(method, left, right, max_disp, backend="onnx", onnx_model=str(tmp))
            both = ref.valid & got.valid
            disparity_difference = float((ref.disparity - got.disparity).abs()[both].max()) if both.any() else 0.0
            valid_agree = bool(torch.equal(ref.valid, got.valid))
    return ExportReport(out, network, methods_of(network), exported.max_difference, disparity_difference, valid_agree)


# ------------------------------------------------------------------------------------------ command line

def build_parser():
    from stereonet.cli.common import OneLineParser

    p = OneLineParser(prog=PROG, description="Export a learned matcher's network to ONNX.")
    sub = p.add_subparsers(dest="format", required=True, metavar="FORMAT", parser_class=OneLineParser)
    o = sub.add_parser("onnx", help="ONNX model for onnxruntime (infer.py --backend onnx)")
    o.add_argument("--method", required=True, help="a learned matcher: dispnet, smd, siamese, siamese-sgm, ...")
    o.add_argument("-o", "--out", type=Path, required=True, help="ONNX file to write (e.g. dispnet.onnx)")
    o.add_argument("--checkpoint", type=Path, default=None, help="weights to export (default: the shipped ones)")
    o.add_argument("--height", type=int, default=DEFAULT_SIZE[0],
                   help=f"height the graph is traced and verified at (default {DEFAULT_SIZE[0]}; any size runs)")
    o.add_argument("--width", type=int, default=DEFAULT_SIZE[1],
                   help=f"width the graph is traced and verified at (default {DEFAULT_SIZE[1]}; any size runs)")
    o.add_argument("--max-disp", type=int, default=DEFAULT_CHECK_MAX_DISP,
                   help=f"disparity range of the end-to-end check of --method (default {DEFAULT_CHECK_MAX_DISP})")
    o.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    return p


def _check_args(args) -> None:
    """Every argument checked, with its command-line name, before anything is computed."""
    from stereonet.matchers.learned import load_network
    from stereonet.models.graphs import min_export_width
    from stereonet.models.weights import default_weights_path

    try:
        network = learned_network(args.method)
    except StereoInputError as e:
        raise StereoInputError(f"--{e}") from None
    try:
        check_writable(args.out, args.overwrite)
    except OSError as e:
        raise type(e)(f"-o: {str(e).removeprefix('out: ')}") from None
    if args.checkpoint is not None and not args.checkpoint.is_file():
        raise FileNotFoundError(f"--checkpoint: no such file: {args.checkpoint}")
    if args.checkpoint is None and not default_weights_path(network).is_file():
        raise FileNotFoundError(f"--method {args.method}: its weights ({default_weights_path(network)}) are missing; "
                                "pass --checkpoint CKPT")
    try:
        net = load_network(network, args.checkpoint)
    except (StereoInputError, FileNotFoundError) as e:
        raise type(e)(f"--{e}") from None
    if args.height < 1:
        raise StereoInputError(f"--height: expected a positive size, got {args.height}")
    smallest = min_export_width(network, net)
    if args.width < smallest:
        raise StereoInputError(f"--width: a {network} graph needs at least {smallest} px, got {args.width}")
    if not 0 < args.max_disp < args.width:
        raise StereoInputError(f"--max-disp: expected 0 < D < --width ({args.width}), got {args.max_disp}")


def main(argv: Sequence[str] | None = None) -> int:
    from stereonet.cli.common import USER_ERRORS, fail

    args = build_parser().parse_args(argv)
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError as e:
        return fail(PROG, f"onnx: {e.name} is not installed (pip install 'stereonet[onnx]')")
    try:
        _check_args(args)
        report = export_onnx(args.method, args.out, args.checkpoint, args.height, args.width, args.max_disp,
                             overwrite=args.overwrite)
    except USER_ERRORS as e:
        return fail(PROG, e)
    except RuntimeError as e:  # the export did not reproduce torch: nothing was written
        return fail(PROG, f"--method {args.method}: {e}", 1)
    check = ""
    if report.disparity_difference is not None:
        check = (f"; {args.method} end to end: max |disparity difference| {report.disparity_difference:.2g} px, "
                 f"valid masks {'equal' if report.valid_agree else 'DIFFER'}")
    print(f"wrote {report.path}: {report.network} graph for {', '.join(report.methods)} (dynamic batch, height, "
          f"width); max output difference vs torch {report.graph_difference:.2g} on the cones pair{check}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
