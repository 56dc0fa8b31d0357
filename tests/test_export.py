"""ONNX export of the learned matchers: onnxruntime reproduces torch on a real pair, the command line, infer.py.

The real pair is the bundled Middlebury 2003 *cones* (im2/im6), downscaled to 112 x 94 so the whole file runs
in well under a minute on one thread; every network is exported once (module fixture) at the default size,
so the matchers run the graph at a size it was not traced at.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

pytest.importorskip("onnx", reason="optional software: the onnx extra (pip install 'stereonet[onnx]') is not installed")
pytest.importorskip("onnxruntime", reason="optional software: the onnx extra is not installed")

from stereonet import export, matchers  # noqa: E402
from stereonet.data import bundled_data_dir  # noqa: E402
from stereonet.io import read_image  # noqa: E402
from stereonet.matchers.learned import NETWORK_OF, methods_of  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CONES = bundled_data_dir() / "middlebury2003" / "cones"
SIZE = (94, 112)  # (H, W): the cones pair / 4, rounded (not the traced 96 x 128, not a multiple of 16)
MAX_DISP = 24  # cones' largest disparity at this scale is ~16 px
TOL_PX = 1e-3
GRAPH_TOL = {"siamese": 1e-3, "dispnet": 1e-2, "smd": 1e-2}
"""Bound on the export check's own torch-vs-graph difference: float32 runtimes differ by ~1e-4 px; the census DispNet
(dispnet.pt, and smd.pt's backbone) by up to ~5e-3 px on the full-size pair (in the padded border rows), still far
below a tracing error (pixels), which the export's own check rejects."""
LEARNED = ("dispnet", "smd", "siamese", "siamese-sgm", "siamese-census-sgm")


@pytest.fixture(scope="module")
def threads():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def cones() -> tuple[torch.Tensor, torch.Tensor]:
    left, right = read_image(CONES / "im2.png"), read_image(CONES / "im6.png")
    return tuple(F.interpolate(x, size=SIZE, mode="area") for x in (left, right))


@pytest.fixture(scope="module")
def onnx_files(tmp_path_factory, threads) -> dict[str, Path]:
    """One exported file per network (the library call behind the command line)."""
    folder = tmp_path_factory.mktemp("onnx")
    files = {}
    for network in ("siamese", "dispnet", "smd"):
        report = export.export_onnx(network, folder / f"{network}.onnx", max_disp=None)
        assert report.network == network and report.methods == methods_of(network)
        assert report.graph_difference <= GRAPH_TOL[network]
        files[network] = report.path
    return files


@pytest.mark.parametrize("method", LEARNED)
def test_onnx_reproduces_torch_on_cones(method, cones, onnx_files, threads):
    left, right = cones
    exact = {"precision": "float32"} if NETWORK_OF[method] == "siamese" else {}  # the ONNX graph is float32
    ref = matchers.match(method, left, right, MAX_DISP, **exact)
    got = matchers.match(method, left, right, MAX_DISP, backend="onnx", onnx_model=str(onnx_files[NETWORK_OF[method]]))
    assert got.disparity.shape == ref.disparity.shape and got.disparity.dtype == ref.disparity.dtype
    assert torch.equal(got.valid, ref.valid)
    both = ref.valid & got.valid
    assert both.float().mean() > 0.5
    difference = float((got.disparity - ref.disparity).abs()[both].max())
    print(f"{method}: max |d_torch - d_onnx| = {difference:.2e} px")
    assert difference <= TOL_PX
    for name in ("confidence", "uncertainty"):
        a, b = getattr(ref, name), getattr(got, name)
        assert (a is None) == (b is None)
        if a is not None:
            torch.testing.assert_close(b, a, rtol=0, atol=TOL_PX)


def test_smd_upsample_and_downscale_to_range_on_onnx(cones, onnx_files, threads):
    """The query grid is an input of the SMD graph: any output scale, and max_disp beyond the trained range."""
    left, right = F.interpolate(cones[0], size=(100, 144), mode="area"), F.interpolate(cones[1], size=(100, 144),
                                                                                         mode="area")
    for options in ({"upsample": 2.0}, {}):
        max_disp = MAX_DISP if options else 120  # 120 > 96 trained: the pair is downscaled by 0.8 first
        ref = matchers.match("smd", left, right, max_disp, **options)
        got = matchers.match("smd", left, right, max_disp, backend="onnx", onnx_model=str(onnx_files["smd"]),
                             **options)
        assert got.disparity.shape == ref.disparity.shape
        assert float((got.disparity - ref.disparity).abs().max()) <= TOL_PX


def test_smd_head_with_context_exports_at_any_size(cones, tmp_path, threads):
    """An SMD head with a neighbourhood (``context``) steps one pixel in the coordinates of the input's own size:
    the exported graph follows the size it is run at (a step baked in at the traced size moved the export check's
    pair by 0.67 px)."""
    from stereonet.models.smd import SMDNet
    from stereonet.models.weights import save_weights

    torch.manual_seed(0)
    config = {"max_disp": 32, "channels": 8, "aggregation": "2d", "upsample": "select", "matching": "census",
              "hidden": [16], "context": 4}
    save_weights(tmp_path / "ctx.pt", "smd", config, SMDNet(**{**config, "hidden": (16,)}))
    report = export.export_onnx("smd", tmp_path / "ctx.onnx", checkpoint=tmp_path / "ctx.pt")
    assert report.graph_difference <= 1e-3
    left, right = cones
    for options in ({"upsample": 2.0}, {}):
        ref = matchers.match("smd", left, right, MAX_DISP, checkpoint=str(tmp_path / "ctx.pt"), **options)
        got = matchers.match("smd", left, right, MAX_DISP, backend="onnx", onnx_model=str(tmp_path / "ctx.onnx"),
                             **options)
        assert float((got.disparity - ref.disparity).abs().max()) <= TOL_PX
        assert float((got.uncertainty - ref.uncertainty).abs().max()) <= TOL_PX


def test_torch_backend_is_the_plain_network(cones, threads):
    """backend='torch' runs the network exactly as predict_disparity / predict_smd do (dispnet's and smd's maps
    before their weighted median, which is not part of the network)."""
    from stereonet.matchers.learned import load_network
    from stereonet.models.dispnet import predict_disparity
    from stereonet.models.smd import MixtureParams, error_probability, predict_smd

    left, right = cones
    out = matchers.match("dispnet", left, right, MAX_DISP)  # the network's map before the check's fill and the filter
    assert torch.equal(out.extras["unfiltered"],
                       predict_disparity(load_network("dispnet"), left, right).clamp(0, MAX_DISP))
    out = matchers.match("smd", left, right, MAX_DISP, wmf_radius=0)  # the head's mode, before the weighted median
    disp, _, mix = predict_smd(load_network("smd"), left, right, with_mixture=True)
    disp = disp.clamp(0, MAX_DISP)
    assert torch.equal(out.disparity, disp)
    # the head's own probability where the left-right check passes (rejected pixels: the fill's, tested elsewhere)
    assert torch.equal(out.uncertainty[out.valid], error_probability(MixtureParams(**mix), disp, 2.0)[out.valid])
    assert out.valid.float().mean() > 0.5
    assert torch.equal(matchers.match("smd", left, right, MAX_DISP).extras["unfiltered"], disp)  # the default


def test_onnx_without_file_exports_in_memory(cones, onnx_files, threads):
    left, right = cones
    ref = matchers.match("siamese", left, right, MAX_DISP, backend="onnx", onnx_model=str(onnx_files["siamese"]))
    got = matchers.match("siamese", left, right, MAX_DISP, backend="onnx")
    assert torch.equal(got.disparity, ref.disparity)


def test_grey_pair_runs_on_onnx(cones, onnx_files, threads):
    left, right = (x.mean(dim=1, keepdim=True) for x in cones)
    for method, exact in (("siamese", {"precision": "float32"}), ("dispnet", {})):
        ref = matchers.match(method, left, right, MAX_DISP, **exact)
        got = matchers.match(method, left, right, MAX_DISP, backend="onnx",
                             onnx_model=str(onnx_files[NETWORK_OF[method]]))
        assert float((got.disparity - ref.disparity).abs().max()) <= TOL_PX


def test_backend_errors_name_the_argument(cones, onnx_files, threads):
    from stereonet.checks import StereoInputError

    left, right = cones
    cases = [
        (dict(backend="tensorrt"), "backend:"),
        (dict(onnx_model=str(onnx_files["dispnet"])), "onnx_model: only used with backend='onnx'"),
        (dict(backend="onnx", onnx_model=str(onnx_files["siamese"])), "onnx_model:"),  # another network
        (dict(backend="onnx", onnx_model=str(onnx_files["dispnet"]), checkpoint="stereonet/weights/dispnet.pt"), "checkpoint:"),
    ]
    for options, message in cases:
        with pytest.raises(StereoInputError, match=message):
            matchers.match("dispnet", left, right, MAX_DISP, **options)
    with pytest.raises(FileNotFoundError, match="onnx_model"):
        matchers.match("dispnet", left, right, MAX_DISP, backend="onnx", onnx_model="no-such.onnx")
    narrow = left[..., :80], right[..., :80]  # the traced correlation spans 25 columns at 1/4: >= 97 px
    with pytest.raises(StereoInputError, match="at least 97 px wide.*backend='torch'"):
        matchers.match("dispnet", *narrow, MAX_DISP, backend="onnx", onnx_model=str(onnx_files["dispnet"]))


def test_metadata_says_what_the_runtime_needs(onnx_files):
    import onnx

    meta = {p.key: p.value for p in onnx.load(str(onnx_files["smd"])).metadata_props}
    assert meta["stereonet.format"] == "stereonet-onnx-v1"
    assert meta["stereonet.network"] == "smd" and meta["stereonet.method"] == "smd"
    assert meta["stereonet.max_disp"] == "96" and meta["stereonet.stride"] == "16"
    assert "standardises" in meta["stereonet.normalisation"]
    assert float(meta["stereonet.verified_max_abs_diff"]) <= GRAPH_TOL["smd"]
    graph = onnx.load(str(onnx_files["smd"])).graph
    assert [i.name for i in graph.input] == ["left", "right", "grid"]
    assert graph.input[0].type.tensor_type.shape.dim[3].dim_param == "width"  # dynamic axes


# ---------------------------------------------------------------------------------------- command line

def test_cli_writes_the_file(tmp_path, capsys, threads):
    out = tmp_path / "models" / "siamese-sgm.onnx"
    code = export.main(["onnx", "--method", "siamese-sgm", "-o", str(out), "--height", "64", "--width", "80"])
    printed = capsys.readouterr().out
    assert code == 0 and out.is_file()
    assert "siamese graph" in printed and "siamese-sgm end to end" in printed and "valid masks equal" in printed
    assert sorted(p.name for p in out.parent.iterdir()) == ["siamese-sgm.onnx"]  # no temporary left behind


def test_python_m_stereonet_export(tmp_path):
    out = tmp_path / "s.onnx"
    run = subprocess.run([sys.executable, "-m", "stereonet.export", "onnx", "--method", "siamese", "-o", str(out),
                          "--max-disp", "16"], cwd=REPO, capture_output=True, text=True, timeout=120,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert run.returncode == 0, run.stderr
    assert out.is_file() and run.stdout.startswith(f"wrote {out}")


def _bad_cases(tmp_path: Path) -> dict[str, tuple[list[str], str]]:
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    existing = tmp_path / "existing.onnx"
    existing.write_text("keep me")
    o = str(tmp_path / "out.onnx")
    return {
        "unknown method": (["--method", "nope", "-o", o], "--method: unknown matcher 'nope'"),
        "classical method": (["--method", "sgm", "-o", o], "--method: 'sgm' is a classical matcher"),
        "missing checkpoint": (["--method", "dispnet", "-o", o, "--checkpoint", str(tmp_path / "x.pt")],
                               "--checkpoint: no such file"),
        "checkpoint of another model": (["--method", "dispnet", "-o", o, "--checkpoint",
                                         str(REPO / "stereonet" / "weights" / "smd.pt")], "--checkpoint: expected a 'dispnet'"),
        "under a file": (["--method", "siamese", "-o", str(a_file / "m.onnx")], "-o: cannot write"),
        "a folder": (["--method", "siamese", "-o", str(tmp_path)], "-o:"),
        "exists": (["--method", "siamese", "-o", str(existing)], "-o: .* already exists"),
        "too narrow": (["--method", "dispnet", "-o", o, "--width", "64"], "--width: .* at least 97"),
        "bad max-disp": (["--method", "siamese", "-o", o, "--max-disp", "0"], "--max-disp:"),
    }


@pytest.mark.parametrize("case", ["unknown method", "classical method", "missing checkpoint",
                                  "checkpoint of another model", "under a file", "a folder", "exists",
                                  "too narrow", "bad max-disp"])
def test_cli_bad_input_is_one_line_exit_2_nothing_written(case, tmp_path, capsys):
    argv, message = _bad_cases(tmp_path)[case]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    code = export.main(["onnx", *argv])
    err = capsys.readouterr().err
    lines = [x for x in err.strip().splitlines() if x]
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith("python -m stereonet.export: error: ") and re.search(message, lines[0]), lines[0]
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "existing.onnx").read_text() == "keep me"


def test_cli_missing_shipped_weights(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("STEREONET_WEIGHTS_DIR", str(tmp_path / "no-weights"))
    code = export.main(["onnx", "--method", "smd", "-o", str(tmp_path / "smd.onnx")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--method smd: its weights" in err
    assert not (tmp_path / "smd.onnx").exists()


# ------------------------------------------------------------------------------------------------ infer.py

def test_infer_backend_onnx_reproduces_torch(cones, onnx_files, tmp_path, capsys, threads):
    from stereonet.cli import infer
    from stereonet.io import read_pfm, write_image

    left, right = tmp_path / "left.png", tmp_path / "right.png"
    write_image(left, cones[0])
    write_image(right, cones[1])
    common = [str(left), str(right), "--method", "dispnet", "--max-disp", str(MAX_DISP), "--no-progress"]
    assert infer.main([*common, "-o", str(tmp_path / "torch")]) == 0
    assert infer.main([*common, "-o", str(tmp_path / "onnx"), "--backend", "onnx",
                       "--onnx-model", str(onnx_files["dispnet"])]) == 0
    a, b = (torch.from_numpy(read_pfm(tmp_path / d / "disparity.pfm").copy()) for d in ("torch", "onnx"))
    assert torch.equal(torch.isfinite(a), torch.isfinite(b))
    finite = torch.isfinite(a)
    assert float((a - b).abs()[finite].max()) <= TOL_PX
    import json

    assert [json.loads((tmp_path / d / "info.json").read_text())["backend"] for d in ("torch", "onnx")] == \
        ["torch", "onnx"]

    bad = {  # one line, exit 2, nothing written
        "classical": (["--method", "sgm", "--backend", "onnx"], "--backend onnx: method 'sgm' is classical"),
        "model without backend": (["--method", "dispnet", "--onnx-model", str(onnx_files["dispnet"])],
                                  "--onnx-model: only used with --backend onnx"),
        "another network": (["--method", "dispnet", "--backend", "onnx", "--onnx-model", str(onnx_files["smd"])],
                            "--onnx-model: .* holds a 'smd' network"),
        "missing model": (["--method", "dispnet", "--backend", "onnx", "--onnx-model", str(tmp_path / "x.onnx")],
                          "--onnx-model: no such file"),
    }
    capsys.readouterr()
    for case, (extra, message) in bad.items():
        out = tmp_path / f"bad-{case}"
        code = infer.main([str(left), str(right), "-o", str(out), "--max-disp", str(MAX_DISP), *extra])
        lines = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(lines) == 1, (case, lines)
        assert lines[0].startswith("infer.py: error: ") and re.search(message, lines[0]), (case, lines[0])
        assert not out.exists()


def test_census_matching_features_are_the_same_bits_in_onnxruntime(threads):
    """DispNet(matching="census") compares census signs of a photo's grey values, many of them equal: the grey
    conversion and the 2x2 means are written so that onnxruntime computes the same bits as torch (a reduction
    in another order flips ties, which moved the exported network's output by up to 0.4 px)."""
    import io

    import onnxruntime as ort

    from stereonet.models.dispnet import DispNet
    from stereonet.models.graphs import OPSET

    net = DispNet(max_disp=32, channels=8, matching="census").eval()

    class Features(torch.nn.Module):
        def forward(self, left, right):
            return net._census_features(left, right)

    left, right = (read_image(CONES / name)[..., :368, :448] for name in ("im2.png", "im6.png"))
    buffer = io.BytesIO()
    torch.onnx.export(Features(), (left, right), buffer, dynamo=False, input_names=["left", "right"],
                      opset_version=OPSET)
    got = ort.InferenceSession(buffer.getvalue()).run(None, {"left": left.numpy(), "right": right.numpy()})
    for expected, value in zip(Features()(left, right), got):
        assert torch.equal(expected, torch.from_numpy(value))


def test_dispnet_matched_readout_exports_to_onnx(threads):
    """DispNet(refine_readout="matched") (the fine stages' soft-argmax over the local correlation) traces into an
    ONNX graph that reproduces torch on a pair of another size than the traced one (dynamic axes), within the
    export's verification tolerance; the logit heads hold non-zero weights, so the read-out is exercised."""
    from stereonet.models.dispnet import DispNet
    from stereonet.models.graphs import (
        ONNX_FORMAT,
        VERIFY_TOLERANCE,
        NetworkGraph,
        OnnxGraph,
        graph_inputs,
        max_output_difference,
        trace_to_onnx,
    )

    torch.manual_seed(0)
    net = DispNet(max_disp=32, channels=8, matching="census", aggregation="3d", upsample="select",
                  refine_readout="matched").eval()
    with torch.no_grad():
        for head in (net.pred1, net.pred0):
            head.weight.normal_(0.0, 0.5)
    graph = NetworkGraph("dispnet", net)
    left, right = (read_image(CONES / name) for name in ("im2.png", "im6.png"))
    example = graph_inputs(graph, left[..., :96, :160], right[..., :96, :160])
    metadata = {"stereonet.format": ONNX_FORMAT, "stereonet.network": "dispnet", "stereonet.stride": "16"}
    exported = OnnxGraph(trace_to_onnx(graph, example, metadata))
    assert max_output_difference(graph, exported, left[..., :128, :224], right[..., :128, :224]) < VERIFY_TOLERANCE
