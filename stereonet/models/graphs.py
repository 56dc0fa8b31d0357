"""The network part of each learned matcher as a graph of plain tensors, run by torch or by onnxruntime.

A *graph* is what :mod:`stereonet.export` writes to ONNX, and the one thing the ``backend`` option of the
learned matchers swaps (:func:`stereonet.matchers.learned.network_graph`); everything around it (downscale
to the trained range, padding, the SMD query grid, cost volumes, SGM, LR check, confidence, upsampling) is
the same code for both backends.

===========  ===================================================  ============================================
network      inputs                                               outputs
===========  ===================================================  ============================================
``siamese``  ``images`` :math:`(N, 3, H, W)`                      ``features`` :math:`(N, F, H, W)`, unit length
``dispnet``  ``left``, ``right`` :math:`(B, 3, H, W)`, H, W       ``disparity`` :math:`(B, 1, H, W)`
             multiples of 16 (padded by the caller)
``smd``      as ``dispnet`` + ``grid`` :math:`(B, Hq, Wq, 2)`     ``mu1``, ``mu2``, ``b1``, ``b2``, ``pi``, each
             (normalised query points, ``align_corners=False``)   :math:`(B, 1, Hq, Wq)`, in input pixels
===========  ===================================================  ============================================

Images are float32 in [0, 1] (grey is given as three equal channels to an ONNX graph); the per-image
standardisation each network applies is inside the graph. N, B, H, W, Hq and Wq are dynamic axes of the
exported file, with one limit that tracing bakes in: DispNet's 1/4-scale correlation loops over
``max_disp // 4 + 1`` columns, so ``dispnet``/``smd`` graphs need a padded width of at least
``4 * (max_disp // 4 + 1)`` (:func:`min_padded_width`; 112 px for the shipped weights). :class:`OnnxGraph`
checks it and says so.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from stereonet.checks import StereoInputError

ONNX_FORMAT = "stereonet-onnx-v1"
GRAPH_INPUTS = {"siamese": ("images",), "dispnet": ("left", "right"), "smd": ("left", "right", "grid")}
GRAPH_OUTPUTS = {"siamese": ("features",), "dispnet": ("disparity",), "smd": ("mu1", "mu2", "b1", "b2", "pi")}
IMAGE_INPUTS = ("images", "left", "right")
NORMALISATION = ("float32 RGB in [0, 1], grey as three equal channels; the graph standardises each image "
                 "itself (zero mean, unit std + 0.01)")


def min_padded_width(network: str, max_disp: int | None) -> int:
    """Smallest padded input width a traced ``network`` graph supports (1 for ``siamese``: no limit)."""
    if network == "siamese" or max_disp is None:
        return 1
    return 4 * (int(max_disp) // 4 + 1)


class NetworkGraph(nn.Module):
    """A loaded network (``SiameseNet``, ``DispNet`` or ``SMDNet``) behind the graph interface of the table
    above: ``graph(*inputs) -> tuple of outputs``. It holds no state of its own (the network's weights only).
    """

    def __init__(self, network: str, net: nn.Module) -> None:
        super().__init__()
        if network not in GRAPH_INPUTS:
            raise StereoInputError(f"network: unknown network {network!r}; valid names: {', '.join(GRAPH_INPUTS)}")
        if network == "siamese":  # oneDNN's channels-last convolutions: ~1.8x faster on CPU, the same maths
            net = net.to(memory_format=torch.channels_last)  # (and the features come out as (H, W, F) rows)
        self.network, self.net = network, net
        self.max_disp: int | None = getattr(net, "max_disp", None)
        self.stride: int = int(getattr(net, "stride", 1))
        self.dtype: torch.dtype = next(net.parameters()).dtype

    def _net_on(self, device: torch.device, dtype: torch.dtype | None = None) -> nn.Module:
        """The network on ``device``, with weights in ``dtype`` (default: as loaded). The loaded one lives on the
        CPU; every other (device, dtype) gets one copy, made the first time it is asked for."""
        first = next(self.net.parameters())
        if first.device == device and dtype in (None, first.dtype):
            return self.net
        copies = self.__dict__.setdefault("_copies", {})
        if (device, dtype) not in copies:
            import copy

            net = copy.deepcopy(self.net).to(device=device)  # (copies keep the channels-last weights)
            if dtype is not None:
                net = net.with_tower_dtype(dtype) if self.network == "siamese" else net.to(dtype=dtype)
            copies[device, dtype] = net
        return copies[device, dtype]

    def features(self, images: torch.Tensor, dtype: torch.dtype | None = None) -> tuple[torch.Tensor]:
        """The ``siamese`` graph with its convolutions in ``dtype`` (default: the weights'; a bfloat16 copy of the
        weights is made once). Not in :meth:`forward`: the ONNX exporter would trace the extra argument."""
        if self.network != "siamese":
            raise StereoInputError(f"dtype: only the 'siamese' network runs in another dtype, not {self.network!r}")
        return (self._net_on(images.device, dtype)(images),)

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        net = self._net_on(inputs[0].device)  # follow the input's device, as every matcher does
        if self.network == "siamese":
            (images,) = inputs
            return (net(images),)
        if self.network == "dispnet":
            left, right = inputs
            return (net(left, right).disparity,)
        left, right, grid = inputs
        mix = net.query(net.backbone(left, right), grid, left=left)
        return mix.mu1, mix.mu2, mix.b1, mix.b2, mix.pi


class OnnxGraph:
    """An exported :class:`NetworkGraph` run by onnxruntime on CPU: called like it, tensors in, tuple out.

    Inputs may live on any device and dtype; they are run as float32 on the CPU and the outputs come back
    as float32 on the first input's device. ``metadata`` holds the file's ``stereonet.*`` properties.

    Args:
        model: path of an ``.onnx`` file written by :mod:`stereonet.export`, or its bytes.
        name: how errors name the model (default: the path).
    """

    def __init__(self, model: str | os.PathLike | bytes, name: str | None = None) -> None:
        import onnxruntime as ort

        self.name = name or (str(model) if not isinstance(model, bytes) else "<in-memory ONNX model>")
        if not isinstance(model, bytes) and not Path(model).is_file():
            raise FileNotFoundError(f"onnx_model: no such file: {self.name}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = torch.get_num_threads()  # the same thread budget as torch
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # errors only
        try:
            self.session = ort.InferenceSession(model if isinstance(model, bytes) else str(model), options,
                                                providers=["CPUExecutionProvider"])
        except Exception as e:  # not an ONNX file, or a graph onnxruntime cannot run
            raise StereoInputError(f"onnx_model: {self.name} is not a readable ONNX model ({e})") from None
        props = self.session.get_modelmeta().custom_metadata_map
        self.metadata = {k[len("stereonet."):]: v for k, v in props.items() if k.startswith("stereonet.")}
        if self.metadata.get("format") != ONNX_FORMAT:
            raise StereoInputError(f"onnx_model: {self.name} was not written by `python -m stereonet.export` "
                                   f"(no {ONNX_FORMAT!r} metadata)")
        self.network = self.metadata["network"]
        max_disp = self.metadata.get("max_disp", "")
        self.max_disp: int | None = int(max_disp) if max_disp else None
        self.stride = int(self.metadata.get("stride", "1"))
        self.min_padded_width = int(self.metadata.get("min_padded_width", "1"))
        self.min_width = int(self.metadata.get("min_width", "1"))
        self.dtype = torch.float32
        self.input_names = [i.name for i in self.session.get_inputs()]
        self.output_names = [o.name for o in self.session.get_outputs()]
        if tuple(self.input_names) != GRAPH_INPUTS.get(self.network):
            raise StereoInputError(f"onnx_model: {self.name} has inputs {self.input_names}, expected "
                                   f"{list(GRAPH_INPUTS.get(self.network, ()))} for a {self.network!r} network")

    def __call__(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        if len(inputs) != len(self.input_names):
            raise StereoInputError(f"inputs: expected {len(self.input_names)} tensors ({', '.join(self.input_names)}), "
                                   f"got {len(inputs)}")
        device = inputs[0].device
        feed: dict[str, np.ndarray] = {}
        for name, x in zip(self.input_names, inputs):
            if name in IMAGE_INPUTS:
                if x.shape[1] == 1:
                    x = x.expand(-1, 3, -1, -1)
                if x.shape[-1] < self.min_padded_width:
                    raise StereoInputError(
                        f"{name}: the {self.network} ONNX graph {self.name} needs images at least {self.min_width} "
                        f"px wide (after any downscale to its {self.max_disp} px range; its correlation was traced "
                        f"over that many columns), got {tuple(x.shape)}; use backend='torch' for narrower images")
            feed[name] = np.ascontiguousarray(x.detach().to("cpu", torch.float32).numpy())
        outputs = self.session.run(self.output_names, feed)
        return tuple(torch.from_numpy(o).to(device) for o in outputs)


def onnx_metadata(network: str, net: nn.Module, config: dict, methods: list[str], **extra: object) -> dict[str, str]:
    """The ``stereonet.*`` metadata of an exported graph (all values strings, as ONNX stores them)."""
    max_disp = getattr(net, "max_disp", None)
    meta = {
        "format": ONNX_FORMAT,
        "network": network,
        "methods": ",".join(methods),
        "max_disp": "" if max_disp is None else str(int(max_disp)),
        "stride": str(int(getattr(net, "stride", 1))),
        "min_padded_width": str(min_padded_width(network, max_disp)),
        "min_width": str(min_export_width(network, net)),
        "config": json.dumps(config, sort_keys=True),
        "inputs": ", ".join(GRAPH_INPUTS[network]),
        "outputs": ", ".join(GRAPH_OUTPUTS[network]),
        "normalisation": NORMALISATION,
        **{k: str(v) for k, v in extra.items()},
    }
    return {f"stereonet.{k}": v for k, v in meta.items()}


def graph_inputs(graph: NetworkGraph | OnnxGraph, left: torch.Tensor, right: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """The inputs of ``graph`` for an image pair :math:`(B, C, H, W)` as the matchers build them (padded to the
    stride, SMD queried at the input size); used to trace and to verify an export."""
    from stereonet.models.layers import InputPadder
    from stereonet.models.smd import padded_query_grid

    left, right = left.to(graph.dtype), right.to(graph.dtype)
    if graph.network == "siamese":
        return (torch.cat([left, right]),)
    b, _, h, w = left.shape
    padder = InputPadder(h, w, graph.stride)
    left_p, right_p = padder.pad(left, right)
    if graph.network == "dispnet":
        return left_p, right_p
    return left_p, right_p, padded_query_grid(b, h, w, padder, device=left.device, dtype=left.dtype)


def _dynamic_axes(network: str) -> dict[str, dict[int, str]]:
    image = {0: "batch", 2: "height", 3: "width"}
    if network == "siamese":
        return {"images": image, "features": image}
    if network == "dispnet":
        return {"left": image, "right": image, "disparity": image}
    query = {0: "batch", 2: "query_height", 3: "query_width"}
    return {"left": image, "right": image, "grid": {0: "batch", 1: "query_height", 2: "query_width"},
            **{name: query for name in GRAPH_OUTPUTS["smd"]}}


OPSET = 17  # GridSample (SMD's queries, DispNet's warps) needs 16


def trace_to_onnx(graph: NetworkGraph, example: tuple[torch.Tensor, ...], metadata: dict[str, str]) -> bytes:
    """Trace ``graph`` on ``example`` inputs into an ONNX model with dynamic batch/size axes; returns its bytes.

    Uses torch's TorchScript-based exporter (``dynamo=False``): on these networks the torch.export-based one
    took ~20x longer and, with dynamic height/width, returned a DispNet graph that was several pixels wrong on
    sizes other than the traced one. The traced graph is only trusted after :func:`verify` says so.
    """
    import io
    import warnings

    import onnx

    buffer = io.BytesIO()
    graph = graph.eval()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # tracer warnings about Python ints (the limit in the module doc)
        torch.onnx.export(graph, example, buffer, dynamo=False, input_names=list(GRAPH_INPUTS[graph.network]),
                          output_names=list(GRAPH_OUTPUTS[graph.network]),
                          dynamic_axes=_dynamic_axes(graph.network), opset_version=OPSET)
    model = onnx.load_from_string(buffer.getvalue())
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    model.producer_name = "stereonet"
    return model.SerializeToString()


def max_output_difference(graph: NetworkGraph, exported: OnnxGraph, left: torch.Tensor,
                          right: torch.Tensor) -> float:
    """Largest absolute difference between the torch graph's and the ONNX graph's outputs on one pair."""
    inputs = graph_inputs(graph, left, right)
    with torch.no_grad():
        expected = graph(*inputs)
    got = exported(*inputs)
    return max(float((a.float() - b.to(a.device).float()).abs().max()) for a, b in zip(expected, got))


VERIFY_TOLERANCE = 1e-2
"""Largest output difference (px of disparity; unit-feature components for ``siamese``) an export may show
against torch on the verification pairs. Float differences between the runtimes are ~1e-4; a graph that
tracing got wrong is off by pixels."""


def verification_pair(height: int | None = None, width: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The bundled Middlebury 2003 *cones* pair (``im2``/``im6``, 450 x 375) as :math:`(1, 3, H, W)`, resized
    to ``height x width`` when given."""
    import torch.nn.functional as F

    from stereonet.data import bundled_data_dir
    from stereonet.io import read_image

    scene = bundled_data_dir() / "middlebury2003" / "cones"
    left, right = (read_image(scene / name).expand(-1, 3, -1, -1) for name in ("im2.png", "im6.png"))
    if height is None or width is None:
        return left, right
    return tuple(F.interpolate(x, size=(height, width), mode="area") for x in (left, right))


def min_export_width(network: str, net: nn.Module) -> int:
    """Smallest image width (before padding) a ``network`` graph can be traced and run at."""
    stride = int(getattr(net, "stride", 1))
    need = min_padded_width(network, getattr(net, "max_disp", None))
    return max(1, (-(-need // stride) - 1) * stride + 1)


@dataclass
class ExportedGraph:
    """An ONNX model (``model`` bytes) and how far it was from torch on the verification pairs."""

    model: bytes
    max_difference: float
    verified_sizes: list[tuple[int, int]]


def export_graph(network: str, net: nn.Module, config: dict, methods: list[str], height: int = 96,
                 width: int = 128, **metadata: object) -> ExportedGraph:
    """Trace the ``network`` graph of ``net`` at ``height x width`` and verify it against torch.

    Verification runs both on :func:`verification_pair` at the traced size and at its full size (so a size
    baked into the graph shows up, and the precision of sums over a real image's pixels is tested);
    RuntimeError if they differ by more than :data:`VERIFY_TOLERANCE`.
    """
    import onnx

    graph = NetworkGraph(network, net).eval()
    smallest = min_export_width(network, net)
    if width < smallest:
        raise StereoInputError(f"width: a {network} graph needs at least {smallest} px (its correlation spans "
                               f"{net.max_disp // 4 + 1} columns at 1/4 scale), got {width}")
    if height < 1:
        raise StereoInputError(f"height: expected a positive size, got {height}")
    meta = onnx_metadata(network, net, config, methods, traced_size=f"{width}x{height}", **metadata)
    model = trace_to_onnx(graph, graph_inputs(graph, *verification_pair(height, width)), meta)
    exported = OnnxGraph(model)
    full = verification_pair()
    sizes = [(height, width), tuple(full[0].shape[-2:])]
    difference = max(max_output_difference(graph, exported, *verification_pair(height, width)),
                     max_output_difference(graph, exported, *full))
    if not difference <= VERIFY_TOLERANCE:
        raise RuntimeError(f"the exported {network} graph differs from torch by {difference:.3g} "
                           f"(tolerance {VERIFY_TOLERANCE}) on the verification pair; not written")
    proto = onnx.load_from_string(model)
    proto.metadata_props.add(key="stereonet.verified_max_abs_diff", value=f"{difference:.3g}")
    proto.metadata_props.add(key="stereonet.verified_sizes", value=", ".join(f"{w}x{h}" for h, w in sizes))
    return ExportedGraph(proto.SerializeToString(), difference, sizes)
