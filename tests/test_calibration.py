import cv2
import numpy as np
import pytest
import torch

from stereonet.calibration import read_calibration, write_opencv_calibration
from stereonet.io import FileFormatError
from stereonet.types import Calibration

MIDDLEBURY = """cam0=[4152.073 0 1288.147; 0 4152.073 973.571; 0 0 1]
cam1=[4152.073 0 1501.231; 0 4152.073 973.571; 0 0 1]
doffs=213.084
baseline=176.252
width=2880
height=1988
ndisp=280
isint=0
vmin=33
vmax=218
dyavg=0
dymax=0
"""

# KITTI raw 2011_09_26 calib_cam_to_cam.txt (excerpt: the rectified colour cameras)
KITTI_RAW = """calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
S_rect_02: 1.242000e+03 3.750000e+02
R_rect_02: 1 0 0 0 1 0 0 0 1
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
S_rect_03: 1.242000e+03 3.750000e+02
P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03
"""

KITTI_ODOMETRY = """P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 4.538225000000e+01 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 -1.130887000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.779761000000e-03
P3: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.372877000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 2.369057000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.915215000000e-03
Tr: 4.276802385584e-04 -9.999672484946e-01 -8.084491683471e-03 -1.198459927713e-02
"""


def test_middlebury_calib_txt(tmp_path):
    (tmp_path / "calib.txt").write_text(MIDDLEBURY)
    c = read_calibration(tmp_path / "calib.txt")
    assert c.focal == pytest.approx(4152.073)
    assert c.K1[0, 2] == pytest.approx(1288.147) and c.K2[0, 2] == pytest.approx(1501.231)
    assert c.doffs == pytest.approx(213.084) and c.ndisp == 280 and c.image_size == (2880, 1988)
    assert torch.allclose(c.R, torch.eye(3, dtype=torch.float64))
    assert torch.allclose(c.t, torch.tensor([-176.252, 0.0, 0.0], dtype=torch.float64))
    assert c.baseline == pytest.approx(176.252)
    # depth of a pixel with disparity d: f * B / (d + doffs) mm
    assert c.focal * c.baseline / (100.0 + c.doffs) == pytest.approx(4152.073 * 176.252 / 313.084)


def test_kitti_raw_cam_to_cam(tmp_path):
    (tmp_path / "calib_cam_to_cam.txt").write_text(KITTI_RAW)
    c = read_calibration(tmp_path / "calib_cam_to_cam.txt")
    assert c.focal == pytest.approx(721.5377) and c.image_size == (1242, 375)
    # t = K^-1 P3[:, 3] - K^-1 P2[:, 3]; x-part = (-339.5242 - 44.85728) / 721.5377 (approx, K's cx term)
    K = np.array([[721.5377, 0, 609.5593], [0, 721.5377, 172.854], [0, 0, 1]])
    t2 = np.linalg.solve(K, [44.85728, 0.2163791, 0.002745884])
    t3 = np.linalg.solve(K, [-339.5242, 2.199936, 0.002729905])
    np.testing.assert_allclose(c.t.numpy(), [(t3 - t2)[0], 0.0, 0.0], rtol=1e-9)  # along x: KITTI's images are rectified
    assert 0.53 < c.baseline < 0.54 and c.t[0] < 0  # right camera ~0.54 m to the right: X_r = X_l - B
    assert c.doffs == 0.0 and c.is_rectified()  # infer.py uses the images as they are


def test_kitti_odometry_style_and_camera_choice(tmp_path):
    (tmp_path / "calib.txt").write_text(KITTI_ODOMETRY)
    grey = read_calibration(tmp_path / "calib.txt", kitti_cameras=(0, 1))
    assert grey.t[0] == pytest.approx(-386.1448 / 718.856)
    colour = read_calibration(tmp_path / "calib.txt")
    assert 0.5 < colour.baseline < 0.6 and colour.image_size is None


def test_opencv_roundtrip_yaml_json_xml(tmp_path):
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    calib = Calibration(np.array([[700.0, 0, 320], [0, 705, 240], [0, 0, 1]]),
                        np.array([[710.0, 0, 330], [0, 712, 245], [0, 0, 1]]), R, np.array([-0.12, 0.001, 0.002]),
                        image_size=(640, 480), dist1=np.array([0.1, -0.05, 0.001, 0.0, 0.01]),
                        dist2=np.array([0.09, -0.04, 0.0, 0.001, 0.0]), ndisp=64)
    for ext in ("yml", "json", "xml"):
        write_opencv_calibration(tmp_path / f"stereo.{ext}", calib)
        back = read_calibration(tmp_path / f"stereo.{ext}")
        for name in ("K1", "K2", "R", "t", "dist1", "dist2"):
            assert torch.allclose(getattr(back, name), getattr(calib, name), rtol=1e-12, atol=1e-14), name
        assert back.image_size == (640, 480) and back.ndisp == 64
    assert not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]


def test_opencv_aliases_and_size_key(tmp_path):
    # as written by common calibration scripts: M1/M2, dist1, size as a list
    text = """%YAML:1.0
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]
M2: [ 500., 0., 322., 0., 500., 240., 0., 0., 1. ]
dist1: [ 0.1, 0.0, 0.0, 0.0, 0.0 ]
R: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]
T: [ -60.0, 0.0, 0.0 ]
size: [ 640, 480 ]
"""
    (tmp_path / "calib.yaml").write_text(text)
    c = read_calibration(tmp_path / "calib.yaml")
    assert c.K2[0, 2] == 322.0 and c.dist1[0] == pytest.approx(0.1) and c.dist2 is None
    assert c.image_size == (640, 480) and c.baseline == pytest.approx(60.0)
    (tmp_path / "c.json").write_text('{"cameraMatrix1": [1,0,2,0,1,3,0,0,1], "cameraMatrix2": [1,0,2,0,1,3,0,0,1],'
                                     ' "R": [1,0,0,0,1,0,0,0,1], "T": [-1,0,0], "image_width": 4, "image_height": 3}')
    assert read_calibration(tmp_path / "c.json").image_size == (4, 3)


@pytest.mark.parametrize("name,content,msg", [
    ("calib.txt", MIDDLEBURY.replace("baseline=176.252\n", ""), r"calib\.txt: missing key 'baseline'"),
    ("calib.txt", MIDDLEBURY.replace("cam1=[4152.073 0 1501.231; 0 4152.073 973.571; 0 0 1]", "cam1=[1 2; 3 4]"),
     r"calib\.txt: malformed 'cam1': expected a 3x3"),
    ("calib.txt", MIDDLEBURY.replace("doffs=213.084", "doffs=abc"), r"malformed 'doffs'"),
    ("kitti.txt", KITTI_RAW.replace("P_rect_03", "P_rect_99"), r"kitti\.txt: missing key 'P_rect_03' or 'P3'"),
    ("kitti.txt", KITTI_RAW.replace("2.729905e-03\n", "\n"), r"malformed 'P_rect_03': expected 12 numbers"),
    ("c.yml", "K1: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nK2: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nT: [1, 0, 0]\n",
     r"c\.yml: missing key 'R'"),
    ("c.yml", "K1: [1, 0, 0]\nK2: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nT: [1, 0, 0]\n",
     r"malformed 'K1': expected 3x3 values"),
    ("c.yml", "K1: [1, 0\n", r"c\.yml: cannot parse"),
    ("c.txt", "hello\n", r"c\.txt: unknown calibration format"),
    ("calib.txt", MIDDLEBURY.replace("cam0=[4152.073", "cam0=[0"), r"calib\.txt: invalid calibration: K1"),
    ("calib.txt", MIDDLEBURY.replace("ndisp=280", "ndisp=inf"), r"malformed 'ndisp': expected a finite number"),
    ("calib.txt", MIDDLEBURY.replace("doffs=213.084", "doffs=nan"), r"malformed 'doffs': expected a finite number"),
    ("calib.txt", MIDDLEBURY.replace("ndisp=280", "ndisp=-16"), r"invalid calibration: ndisp"),
    ("c.yml", "K1: [[1, 0, 0], [0, 1, 0], [0, 0]]\nK2: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
              "T: [1, 0, 0]\n", r"malformed 'K1': expected rows of equal length"),
])
def test_malformed_files_name_file_and_key(tmp_path, name, content, msg):
    (tmp_path / name).write_text(content)
    with pytest.raises(FileFormatError, match=msg):
        read_calibration(tmp_path / name)


def test_missing_file_and_bad_write(tmp_path):
    with pytest.raises(FileNotFoundError, match="none.txt"):
        read_calibration(tmp_path / "none.txt")
    with pytest.raises(ValueError, match="path: expected one of"):
        write_opencv_calibration(tmp_path / "c.txt", Calibration.rectified(500, 320, 240, 0.1))


# ------------------------------------------------------------------------------------------ OpenCV two-file
# What OpenCV's samples/cpp/stereo_calib.cpp writes: intrinsics.yml (M1, D1, M2, D2) and extrinsics.yml
# (R, T, R1, R2, P1, P2, Q), no image size.
TWO_FILE_K1 = np.array([[500.0, 0.0, 81.0], [0.0, 500.0, 59.0], [0.0, 0.0, 1.0]])
TWO_FILE_K2 = np.array([[505.0, 0.0, 79.0], [0.0, 505.0, 61.0], [0.0, 0.0, 1.0]])
TWO_FILE_R = cv2.Rodrigues(np.array([0.002, 0.01, -0.003]))[0]
TWO_FILE_T = np.array([[-0.12], [0.001], [0.002]])


def write_two_files(folder, intrinsics="intrinsics.yml", extrinsics="extrinsics.yml"):
    folder.mkdir(parents=True, exist_ok=True)
    D1, D2 = np.array([[-0.1, 0.02, 0.0, 0.0, 0.0]]), np.array([[-0.08, 0.01, 0.0, 0.0, 0.0]])
    if intrinsics is not None:
        fs = cv2.FileStorage(str(folder / intrinsics), cv2.FILE_STORAGE_WRITE)
        for key, value in (("M1", TWO_FILE_K1), ("D1", D1), ("M2", TWO_FILE_K2), ("D2", D2)):
            fs.write(key, value)
        fs.release()
    if extrinsics is not None:
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(TWO_FILE_K1, D1, TWO_FILE_K2, D2, (160, 120), TWO_FILE_R,
                                                    TWO_FILE_T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
        fs = cv2.FileStorage(str(folder / extrinsics), cv2.FILE_STORAGE_WRITE)
        for key, value in (("R", TWO_FILE_R), ("T", TWO_FILE_T), ("R1", R1), ("R2", R2), ("P1", P1), ("P2", P2),
                           ("Q", Q)):
            fs.write(key, value)
        fs.release()
    return folder


@pytest.mark.parametrize("given", ["intrinsics.yml", "extrinsics.yml"])
def test_opencv_two_file_output_is_read_from_either_file(tmp_path, given):
    write_two_files(tmp_path)
    c = read_calibration(tmp_path / given)
    assert np.allclose(c.K1.numpy(), TWO_FILE_K1) and np.allclose(c.K2.numpy(), TWO_FILE_K2)
    assert np.allclose(c.R.numpy(), TWO_FILE_R) and np.allclose(c.t.numpy(), TWO_FILE_T.ravel())
    assert c.dist1[0] == pytest.approx(-0.1) and c.dist2[0] == pytest.approx(-0.08)
    assert c.image_size is None  # not in those files: infer.py takes it from the images


def test_opencv_two_file_names_keep_prefix_case_and_mixed_extensions(tmp_path):
    write_two_files(tmp_path, "rigA_Intrinsics.yaml", "rigA_Extrinsics.yml")
    assert read_calibration(tmp_path / "rigA_Intrinsics.yaml").baseline == pytest.approx(0.12, rel=1e-3)
    assert read_calibration(tmp_path / "rigA_Extrinsics.yml").K1[0, 0] == 500.0


@pytest.mark.parametrize("present,given,msg", [
    ("intrinsics", "intrinsics.yml", r"intrinsics\.yml: missing key 'R'; OpenCV's two-file output needs "
                                     r"extrinsics\.yml beside it, not found"),
    ("extrinsics", "extrinsics.yml", r"extrinsics\.yml: missing key 'K1' \(also accepted: M1, cameraMatrix1, "
                                     r"camera_matrix_1\); OpenCV's two-file output needs intrinsics\.yml beside it"),
])
def test_opencv_two_file_with_one_file_missing_names_the_other(tmp_path, present, given, msg):
    write_two_files(tmp_path, intrinsics="intrinsics.yml" if present == "intrinsics" else None,
                    extrinsics="extrinsics.yml" if present == "extrinsics" else None)
    with pytest.raises(FileFormatError, match=msg):
        read_calibration(tmp_path / given)


def test_missing_key_without_aliases_has_no_empty_alias_list(tmp_path):
    (tmp_path / "c.yml").write_text("K1: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nK2: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nT: [1, 0, 0]\n")
    with pytest.raises(FileFormatError) as info:
        read_calibration(tmp_path / "c.yml")
    assert str(info.value).endswith("c.yml: missing key 'R'")
    (tmp_path / "c.yml").write_text("K1: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nT: [1, 0, 0]\n")
    with pytest.raises(FileFormatError, match=r"missing key 'K2' \(also accepted: M2, cameraMatrix2, camera_matrix_2\)$"):
        read_calibration(tmp_path / "c.yml")


def test_write_extra_keys_round_trip(tmp_path):
    calib = Calibration.rectified(500, 320, 240, 0.1, image_size=(640, 480))
    write_opencv_calibration(tmp_path / "c.yaml", calib, extra={"unit": "m", "rms_px": 0.25,
                                                                "per_view": np.ones((2, 3))})
    fs = cv2.FileStorage(str(tmp_path / "c.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("unit").string() == "m" and fs.getNode("rms_px").real() == 0.25
    assert fs.getNode("per_view").mat().shape == (2, 3)
    fs.release()
    assert read_calibration(tmp_path / "c.yaml").baseline == pytest.approx(0.1)
    with pytest.raises(ValueError, match="extra: 'size' is a calibration key"):
        write_opencv_calibration(tmp_path / "d.yaml", calib, extra={"size": 3})
    assert not (tmp_path / "d.yaml").exists()


def test_infer_takes_the_image_size_of_a_two_file_calibration_from_the_images(tmp_path):
    from stereonet.cli.infer import main

    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur((rng.random((120, 176)) * 255).astype(np.uint8), (3, 3), 0)
    cv2.imwrite(str(tmp_path / "left.png"), texture[:, 8:168])
    cv2.imwrite(str(tmp_path / "right.png"), texture[:, 4:164])
    write_two_files(tmp_path / "calib")
    out = tmp_path / "out"
    code = main([str(tmp_path / "left.png"), str(tmp_path / "right.png"), "-o", str(out), "--method", "opencv-sgbm",
                 "--max-disp", "16", "--calib", str(tmp_path / "calib" / "intrinsics.yml")])
    assert code == 0
    import json

    assert json.loads((out / "info.json").read_text())["rectified"] == "calibrated"
    assert (out / "rectified_left.png").is_file() and (out / "depth.pfm").is_file()


def test_opencv_file_without_doffs_takes_the_principal_points_difference(tmp_path):
    """A rectified rig whose cameras' cx differ (P1/P2 from stereoRectify without CALIB_ZERO_DISPARITY), written
    without a doffs key: doffs = cx2 - cx1, as the Middlebury and KITTI readers take it (was 0: depth off)."""
    path = tmp_path / "rig.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("K1", np.array([[700.0, 0, 300], [0, 700, 240], [0, 0, 1]]))
    fs.write("K2", np.array([[700.0, 0, 340], [0, 700, 240], [0, 0, 1]]))
    fs.write("R", np.eye(3))
    fs.write("T", np.array([[-120.0], [0.0], [0.0]]))
    fs.release()
    c = read_calibration(path)
    assert c.is_rectified() and c.doffs == pytest.approx(40.0)
