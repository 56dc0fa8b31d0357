"""stereonet.calibrate and stereonet-calibrate on chessboard pairs rendered for a known, distorted rig.

The renderer: every (2x supersampled) pixel of each camera is turned into its ray with data_gen's camera
model (``Camera.pixel_to_normalized``: OpenCV distortion inverted to ~1e-10), the ray meets the board plane
(a homography, since the board is planar), and the board texture is sampled there (``cv2.remap``); 2x2 area
averaging, a contrast change and 1.5 grey levels of noise follow. Corners found in these images lie 0.04 px
(mean) from the true projections.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from data_gen.camera import Camera
from stereonet.calibrate import Board, Detection, align_detection, calibrate_rig, detect_board, outlier_views
from stereonet.calibration import read_calibration
from stereonet.cli.calibrate import main

W, H = 640, 480
COLS, ROWS, SQUARE = 9, 6, 30.0  # inner corners, mm
K1 = np.array([[600.0, 0.0, 322.0], [0.0, 602.0, 238.0], [0.0, 0.0, 1.0]])
K2 = np.array([[610.0, 0.0, 315.0], [0.0, 608.0, 244.0], [0.0, 0.0, 1.0]])
D1 = np.array([-0.25, 0.08, 0.001, -0.0005, 0.0])  # barrel distortion, ~9 px at the image corners
D2 = np.array([-0.20, 0.05, -0.0008, 0.0006, 0.0])
R_TRUE = cv2.Rodrigues(np.array([0.01, -0.03, 0.005]))[0]  # 1.8 degrees
T_TRUE = np.array([-60.0, 0.5, 1.0])  # X_r = R X_l + t: the right camera 60 mm to the right
VIEWS = 14
TEXTURE_PX = 40  # texture pixels per square
SUPERSAMPLE = 2


def cameras() -> list[Camera]:
    return [Camera(K1, np.eye(3), np.zeros(3), (W, H), D1), Camera(K2, R_TRUE, T_TRUE, (W, H), D2)]


def chessboard_texture() -> tuple[np.ndarray, float]:
    """The board picture (black corner squares, one white square of margin) and where corner 0 sits in it,
    in squares from its top-left edge."""
    tex = np.full(((ROWS + 3) * TEXTURE_PX, (COLS + 3) * TEXTURE_PX), 255, np.uint8)
    for j in range(ROWS + 1):
        for i in range(COLS + 1):
            if (i + j) % 2 == 0:
                y0, x0 = (j + 1) * TEXTURE_PX, (i + 1) * TEXTURE_PX
                tex[y0:y0 + TEXTURE_PX, x0:x0 + TEXTURE_PX] = 0
    return tex, 2.0


def charuco_texture(board: Board) -> tuple[np.ndarray, float]:
    """OpenCV's own picture of the ChArUco board with one square of white margin; its corner 0 is at
    (square, square) on the board, 2 squares from the picture's edge."""
    size = ((COLS + 3) * TEXTURE_PX, (ROWS + 3) * TEXTURE_PX)
    return board.charuco().generateImage(size, marginSize=TEXTURE_PX), 1.0


def camera_rays(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates of the camera's supersampled pixel grid (pose independent)."""
    xs, ys = cam.sample_coords(SUPERSAMPLE)
    return cam.pixel_to_normalized(*np.meshgrid(xs, ys))


def render(cam: Camera, rays, Rb, tb, texture, origin: float, rng) -> np.ndarray:
    """The board at pose ``X_world = Rb (X, Y, 0) + tb`` seen by ``cam``: uint8 (H, W)."""
    Rc, tc = cam.R @ Rb, cam.R @ tb + cam.t
    to_board = np.linalg.inv(np.column_stack([Rc[:, 0], Rc[:, 1], tc]))  # normalized -> board (X, Y, 1)
    xn, yn = rays
    b = np.stack([xn, yn, np.ones_like(xn)], -1) @ to_board.T
    u = (b[..., 0] / b[..., 2] / SQUARE + origin) * TEXTURE_PX - 0.5
    v = (b[..., 1] / b[..., 2] / SQUARE + origin) * TEXTURE_PX - 0.5
    img = cv2.remap(texture.astype(np.float32), u.astype(np.float32), v.astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=110.0)
    img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA) * 0.85 + 20 + rng.normal(0, 1.5, (H, W))
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def board_poses(obj: np.ndarray, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` poses tilted up to ~35 degrees in turning directions, 0.38-0.65 m away, with the whole board
    (corners ``obj`` plus one square around them) inside both images."""
    rng = np.random.default_rng(seed)
    lo, hi = obj[:, :2].min(0) - SQUARE, obj[:, :2].max(0) + SQUARE
    outline = np.array([[x, y, 0.0] for x in np.linspace(lo[0], hi[0], 5) for y in np.linspace(lo[1], hi[1], 5)])
    middle = np.append((lo + hi) / 2, 0.0)
    cams, poses = cameras(), []
    while len(poses) < n:
        angle = 2 * np.pi * len(poses) / n + rng.uniform(-0.3, 0.3)
        tilt = 0.6 * rng.uniform(0.5, 1.0)
        Rb = cv2.Rodrigues(np.array([tilt * np.cos(angle), tilt * np.sin(angle), rng.uniform(-0.4, 0.4)]))[0]
        z = rng.uniform(380, 650)
        tb = np.array([rng.uniform(-0.3, 0.3) * z, rng.uniform(-0.22, 0.22) * z, z]) - Rb @ middle
        inside = True
        for cam in cams:
            P = (outline @ Rb.T + tb) @ cam.R.T + cam.t
            px = cv2.projectPoints(P, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0].reshape(-1, 2)
            inside &= bool((px >= 4).all() and (px[:, 0] <= W - 5).all() and (px[:, 1] <= H - 5).all())
        if inside:
            poses.append((Rb, tb))
    return poses


def render_rig(folder: Path, board: Board, texture, origin: float, seed: int) -> Path:
    """Write ``folder/left/left_XX.png`` and ``folder/right/right_XX.png``, ``VIEWS`` views."""
    rng = np.random.default_rng(seed + 100)
    cams = cameras()
    rays = [camera_rays(c) for c in cams]
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
    for k, (Rb, tb) in enumerate(board_poses(board.object_points().astype(np.float64), VIEWS, seed)):
        for side, cam, r in zip(("left", "right"), cams, rays):
            cv2.imwrite(str(folder / side / f"{side}_{k:02d}.png"), render(cam, r, Rb, tb, texture, origin, rng))
    return folder


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> Path:
    return render_rig(tmp_path_factory.mktemp("rig"), Board(COLS, ROWS, SQUARE), *chessboard_texture(), seed=0)


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_matches_truth(calib) -> None:
    for K, K_true in ((calib.K1, K1), (calib.K2, K2)):
        for i in (0, 1):
            assert float(K[i, i]) == pytest.approx(K_true[i, i], rel=0.005)  # focal lengths within 0.5 %
            assert float(K[i, 2]) == pytest.approx(K_true[i, 2], abs=3.0)
    assert calib.baseline == pytest.approx(float(np.linalg.norm(T_TRUE)), rel=0.005)
    angle = np.degrees(np.linalg.norm(cv2.Rodrigues(calib.R.numpy() @ R_TRUE.T)[0]))
    assert angle < 0.1
    assert np.degrees(math.acos(float(calib.t.numpy() @ T_TRUE) / calib.baseline / np.linalg.norm(T_TRUE))) < 0.5
    assert float(calib.dist1[0]) == pytest.approx(D1[0], abs=0.02)
    assert float(calib.dist2[0]) == pytest.approx(D2[0], abs=0.02)


# ------------------------------------------------------------------------------------------ the tool

def test_calibrates_a_rendered_rig_to_the_truth(rig, tmp_path, capsys):
    out = tmp_path / "rig.yaml"
    code, stdout, stderr = run(capsys, rig / "left", rig / "right", "--board", f"{COLS}x{ROWS}",
                               "--square", SQUARE, "--unit", "mm", "-o", out)
    assert code == 0, stderr
    calib = read_calibration(out)  # what infer.py --calib reads
    assert calib.image_size == (W, H)
    assert_matches_truth(calib)
    # per-view table: a header and one row per view, all used
    rows = [line for line in stdout.splitlines() if line.strip().startswith(tuple("0123456789"))]
    assert stdout.splitlines()[0].split()[:3] == ["view", "left", "right"]
    assert len(rows) == VIEWS and all(r.rstrip().endswith("used") for r in rows)
    assert "rectified row error" in stdout and stderr == ""
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    assert fs.getNode("unit").string() == "mm" and int(fs.getNode("views_used").real()) == VIEWS
    assert fs.getNode("rms_px").real() < 0.2 and fs.getNode("rectified_row_error_px").real() < 0.1
    E, F = fs.getNode("E").mat(), fs.getNode("F").mat()
    fs.release()
    t = calib.t.numpy()
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    np.testing.assert_allclose(E, tx @ calib.R.numpy(), rtol=1e-9, atol=1e-12)  # OpenCV's E = [T]x R
    X1 = np.array([[30.0, -20.0, 600.0], [-50.0, 40.0, 900.0]])  # two points in front of the rig (mm)
    X2 = X1 @ calib.R.numpy().T + t
    x1 = (X1 @ calib.K1.numpy().T)
    x2 = (X2 @ calib.K2.numpy().T)
    x1, x2 = x1 / x1[:, 2:], x2 / x2[:, 2:]
    assert np.abs(np.einsum("ij,jk,ik->i", x2, F, x1)).max() < 1e-6  # x2^T F x1 = 0
    preview = cv2.imread(str(tmp_path / "rig_preview.png"))
    assert preview.shape == (H, 2 * W, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml", "rig_preview.png"]  # no temporary left


def test_globs_fixed_intrinsics_and_preview_path(rig, tmp_path, capsys):
    out, preview = tmp_path / "c.yml", tmp_path / "pics" / "check.png"
    code, _, stderr = run(capsys, f"{rig}/left/left_*.png", f"{rig}/right/right_*.png", "--board", "9x6",
                          "--square", SQUARE, "-o", out, "--preview", preview, "--fix-intrinsics")
    assert code == 0, stderr
    assert_matches_truth(read_calibration(out))
    assert preview.is_file() and not (tmp_path / "c_preview.png").exists()


def test_python_m_and_console_script_entry(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "stereonet.calibrate", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "--board" in proc.stdout and "--square" in proc.stdout
    import tomllib

    scripts = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["stereonet-calibrate"] == "stereonet.cli.calibrate:main"


def test_charuco_board(tmp_path, capsys):
    board = Board(COLS, ROWS, SQUARE, dictionary="DICT_4X4_50")
    folder = render_rig(tmp_path / "charuco", board, *charuco_texture(board), seed=1)
    out = tmp_path / "charuco.yaml"
    code, _, stderr = run(capsys, folder / "left", folder / "right", "--board", "9x6", "--square", SQUARE,
                          "--charuco", "DICT_4X4_50", "-o", out)
    assert code == 0, stderr
    assert_matches_truth(read_calibration(out))


# ------------------------------------------------------------------------------------------ library

@pytest.fixture(scope="module")
def detections(rig):
    board = Board(COLS, ROWS, SQUARE)
    found = []
    for side in ("left", "right"):
        files = sorted((rig / side).glob("*.png"))
        found.append([detect_board(board, cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)) for f in files])
    return board, found[0], found[1]


def test_outlier_view_is_dropped_and_the_rest_recalibrated(detections):
    board, left, right = detections
    right = list(right)
    rng = np.random.default_rng(0)
    bad = right[3]
    right[3] = Detection(bad.ids, (bad.points + rng.normal(0, 3.0, bad.points.shape)).astype(np.float32))
    result = calibrate_rig(board, left, right, (W, H))
    assert result.views[3].status.startswith("dropped: outlier")
    assert result.used == [i for i in range(VIEWS) if i != 3]
    assert any("view 3" in w and "outlier" in w for w in result.warnings)
    assert_matches_truth(result.calib)


def test_outlier_rule():
    assert outlier_views(np.array([0.1, 0.12, 0.9, 0.11])).tolist() == [False, False, False, False]  # < 1 px
    assert outlier_views(np.array([1.0, 1.1, 5.0, 0.9])).tolist() == [False, False, True, False]  # > 3x median
    assert outlier_views(np.zeros(0)).size == 0


def test_align_detection_undoes_a_half_turn_of_the_corner_order(detections):
    board, left, right = detections
    flipped = Detection(right[0].ids, right[0].points[::-1].copy())
    assert np.array_equal(align_detection(board, left[0], flipped).points, right[0].points)
    assert np.array_equal(align_detection(board, left[0], right[0]).points, right[0].points)


# ------------------------------------------------------------------------------------------ bad input

def copy_views(rig: Path, dest: Path, views) -> Path:
    for side in ("left", "right"):
        (dest / side).mkdir(parents=True)
        for k in views:
            shutil.copy(rig / side / f"{side}_{k:02d}.png", dest / side)
    return dest


def assert_refused(code: int, stderr: str, tmp_path: Path, *needles: str) -> None:
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stereonet-calibrate: error: "), stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert not (tmp_path / "out.yaml").exists() and not (tmp_path / "out_preview.png").exists()
    assert not list(tmp_path.glob(".out*"))  # no temporary file either


def test_too_few_views_says_how_many_and_which(rig, tmp_path, capsys):
    code, _, err = run(capsys, f"{rig}/left/left_0[0-2].png", f"{rig}/right/right_0[0-2].png", "--board", "9x6",
                       "--square", SQUARE, "-o", tmp_path / "out.yaml")
    assert_refused(code, err, tmp_path, "3 of 3 views", "left_00.png", "left_02.png", "at least 6")


def test_wrong_board_size(rig, tmp_path, capsys):
    code, _, err = run(capsys, f"{rig}/left/left_0[0-2].png", f"{rig}/right/right_0[0-2].png", "--board", "10x7",
                       "--square", SQUARE, "-o", tmp_path / "out.yaml")
    assert_refused(code, err, tmp_path, "10x7", "not found in any", "--board")


def test_images_of_different_sizes(rig, tmp_path, capsys):
    data = copy_views(rig, tmp_path / "data", range(3))
    small = cv2.resize(cv2.imread(str(data / "right" / "right_01.png")), (600, 450))
    cv2.imwrite(str(data / "right" / "right_01.png"), small)
    code, _, err = run(capsys, data / "left", data / "right", "--board", "9x6", "--square", SQUARE,
                       "-o", tmp_path / "out.yaml")
    assert_refused(code, err, tmp_path, "right_01.png is 600x450", "expected 640x480")


def test_left_and_right_of_different_lengths(rig, tmp_path, capsys):
    data = copy_views(rig, tmp_path / "data", range(4))
    (data / "right" / "right_03.png").unlink()
    code, _, err = run(capsys, data / "left", data / "right", "--board", "9x6", "--square", SQUARE,
                       "-o", tmp_path / "out.yaml")
    assert_refused(code, err, tmp_path, "RIGHT", "without a partner: left_03.png")  # paired by number


@pytest.fixture
def one_sided(rig, tmp_path) -> Path:
    """Every view, but the board hidden in the right image of view 5 (a grey frame)."""
    data = copy_views(rig, tmp_path / "data", range(VIEWS))
    cv2.imwrite(str(data / "right" / "right_05.png"), np.full((H, W), 120, np.uint8))
    return data


def test_view_seen_by_one_camera_is_dropped_with_a_warning(one_sided, tmp_path, capsys):
    out = tmp_path / "ok.yaml"
    code, stdout, err = run(capsys, one_sided / "left", one_sided / "right", "--board", "9x6", "--square", SQUARE,
                            "-o", out)
    assert code == 0
    assert err.count("\n") == 1 and "warning" in err and "left_05.png" in err and "left image only" in err
    assert "dropped: board found in the left image only" in stdout
    assert_matches_truth(read_calibration(out))


def test_view_seen_by_one_camera_is_an_error_when_too_few_remain(one_sided, tmp_path, capsys):
    code, _, err = run(capsys, one_sided / "left", one_sided / "right", "--board", "9x6", "--square", SQUARE,
                       "--min-views", VIEWS, "-o", tmp_path / "out.yaml")
    assert_refused(code, err, tmp_path, f"{VIEWS - 1} of {VIEWS} views", "left_05.png (left only)")


@pytest.mark.parametrize("args,needle", [
    (["--board", "9by6"], "--board: expected inner corners as COLSxROWS"),
    (["--board", "9x1"], "at least 2x2"),
    (["--square", "0"], "--square: expected a positive size"),
    (["-o", "{tmp}/out.txt"], "-o: expected a .yaml"),
    (["--preview", "{tmp}/p.jpg"], "--preview: expected a .png"),
    (["--charuco", "DICT_NOPE"], "--charuco: expected one of"),
    (["--marker", "10"], "--marker: only for a ChArUco board"),
    (["--min-views", "2"], "--min-views: expected at least 3"),
])
def test_bad_arguments(rig, tmp_path, capsys, args, needle):
    base = {"--board": "9x6", "--square": str(SQUARE), "-o": str(tmp_path / "out.yaml")}
    base.update({k: v.format(tmp=tmp_path) for k, v in zip(args[::2], args[1::2])})
    code, _, err = run(capsys, rig / "left", rig / "right", *[x for kv in base.items() for x in kv])
    assert_refused(code, err, tmp_path, needle)


def test_existing_output_needs_overwrite(rig, tmp_path, capsys):
    (tmp_path / "out.yaml").write_text("keep me")
    code, _, err = run(capsys, rig / "left", rig / "right", "--board", "9x6", "--square", SQUARE,
                       "-o", tmp_path / "out.yaml")
    assert code == 2 and "--overwrite" in err and (tmp_path / "out.yaml").read_text() == "keep me"


def test_missing_folder(tmp_path, capsys):
    code, _, err = run(capsys, tmp_path / "nope", tmp_path / "nope2", "--board", "9x6", "--square", SQUARE,
                       "-o", tmp_path / "out.yaml")
    assert_refused(code, err, tmp_path, "LEFT", "nope")


@pytest.mark.parametrize("shape", [(1, 1), (12, 40), (40, 12)])
def test_detect_board_finds_nothing_in_an_image_too_small_to_show_it(shape):
    board = Board(9, 6, 25.0)
    assert detect_board(board, np.full(shape, 128, np.uint8)) is None  # not an OpenCV assertion


def test_videos_are_refused_in_one_line(tmp_path, capsys):
    """Two videos (infer.py's frame-by-frame input) are not board images: one line naming LEFT."""
    for name in ("left.avi", "right.avi"):
        writer = cv2.VideoWriter(str(tmp_path / name), cv2.VideoWriter_fourcc(*"MJPG"), 5, (64, 48))
        if not writer.isOpened():
            pytest.skip("this OpenCV build cannot write MJPG video")
        for _ in range(2):
            writer.write(np.full((48, 64, 3), 128, np.uint8))
        writer.release()
    code, _, err = run(capsys, tmp_path / "left.avi", tmp_path / "right.avi", "--board", "9x6", "--square", SQUARE,
                       "-o", tmp_path / "out.yaml")
    assert_refused(code, err, tmp_path, "LEFT", "videos")
