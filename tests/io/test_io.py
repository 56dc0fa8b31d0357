import struct

import cv2
import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.io import (
    FileFormatError,
    read_disparity,
    read_image,
    read_pfm,
    read_ply,
    write_disparity_pfm,
    write_disparity_png8,
    write_disparity_png16,
    write_image,
    write_pfm,
    write_ply,
)


def _no_temp_files(folder):
    return not [p.name for p in folder.iterdir() if ".tmp-" in p.name]


# ---------------------------------------------------------------- PFM
@pytest.mark.parametrize("little", [True, False])
@pytest.mark.parametrize("shape", [(5, 7), (4, 6, 3)])
def test_pfm_roundtrip(tmp_path, little, shape):
    a = np.random.default_rng(0).normal(size=shape).astype(np.float32)
    a[0, 0] = np.inf
    write_pfm(tmp_path / "a.pfm", a, little_endian=little)
    b = read_pfm(tmp_path / "a.pfm")
    assert b.dtype == np.float32 and b.shape == shape
    np.testing.assert_array_equal(a, b)
    assert (tmp_path / "a.pfm").read_bytes()[:2] == (b"Pf" if len(shape) == 2 else b"PF")
    assert _no_temp_files(tmp_path)


@pytest.mark.parametrize("endian,scale", [(">", 1.0), ("<", -1.0), (">", 2.5)])
def test_pfm_hand_made_rows_bottom_to_top(tmp_path, endian, scale):
    # rows stored bottom first: the file's first row [3, 4] is the bottom image row
    body = struct.pack(f"{endian}4f", 3.0, 4.0, 1.0, 2.0)
    (tmp_path / "h.pfm").write_bytes(b"Pf\n2\n2\n" + f"{scale}\n".encode() + body)
    np.testing.assert_array_equal(read_pfm(tmp_path / "h.pfm"), [[1.0, 2.0], [3.0, 4.0]])


def test_pfm_colour_channel_order(tmp_path):
    body = struct.pack("<6f", 1, 2, 3, 4, 5, 6)  # one row, two RGB pixels
    (tmp_path / "c.pfm").write_bytes(b"PF 2 1 -1.0\n" + body)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), [[[1, 2, 3], [4, 5, 6]]])


def test_pfm_accepts_torch_and_leading_ones(tmp_path):
    t = torch.arange(12, dtype=torch.float32).reshape(1, 1, 3, 4)
    write_pfm(tmp_path / "t.pfm", t)
    np.testing.assert_array_equal(read_pfm(tmp_path / "t.pfm"), t[0, 0].numpy())
    with pytest.raises(ValueError, match="arr: expected shape"):
        write_pfm(tmp_path / "bad.pfm", np.zeros((2, 3, 4, 5)))


def test_pfm_truncated(tmp_path):
    write_pfm(tmp_path / "disp.pfm", np.zeros((32, 32), np.float32))
    data = (tmp_path / "disp.pfm").read_bytes()
    header_len = len(data) - 32 * 32 * 4
    (tmp_path / "disp.pfm").write_bytes(data[:header_len + 100])
    with pytest.raises(FileFormatError, match=r"disp\.pfm: truncated, expected 4096 bytes of data, got 100"):
        read_pfm(tmp_path / "disp.pfm")


@pytest.mark.parametrize("content,msg", [
    (b"P6\n2 2\n255\n", "not a PFM file"),
    (b"Pf\n2 x\n-1\n" + bytes(16), "expected integer width and height"),
    (b"Pf\n2 2\nabc\n" + bytes(16), "expected a float scale"),
    (b"Pf\n2 2\n0\n" + bytes(16), "non-zero finite scale"),
    (b"Pf\n2", "truncated or corrupt PFM header"),
    (b"", "not a PFM file"),
])
def test_pfm_corrupt(tmp_path, content, msg):
    (tmp_path / "bad.pfm").write_bytes(content)
    with pytest.raises(FileFormatError, match=msg) as e:
        read_pfm(tmp_path / "bad.pfm")
    assert "bad.pfm" in str(e.value)
    assert isinstance(e.value, StereoInputError)


def test_missing_files_named(tmp_path):
    for fn in (read_pfm, read_image, read_ply, read_disparity):
        with pytest.raises(FileNotFoundError, match="nope.xyz"):
            fn(tmp_path / "nope.xyz")


# ---------------------------------------------------------------- images
def test_image_roundtrip_png_ppm_and_rgb_order(tmp_path):
    g = torch.Generator().manual_seed(0)
    img = (torch.randint(0, 256, (1, 3, 5, 6), generator=g).float() / 255)
    for ext in ("png", "ppm", "bmp"):
        write_image(tmp_path / f"a.{ext}", img)
        back = read_image(tmp_path / f"a.{ext}")
        assert back.shape == (1, 3, 5, 6) and back.dtype == torch.float32
        torch.testing.assert_close(back, img, atol=1e-6, rtol=0)
    red = torch.zeros(3, 4, 4)
    red[0] = 1.0
    write_image(tmp_path / "red.png", red)
    bgr = cv2.imread(str(tmp_path / "red.png"))
    assert bgr[..., 2].min() == 255 and bgr[..., :2].max() == 0  # OpenCV sees red in its last channel
    assert read_image(tmp_path / "red.png")[0, 0].min() == 1.0
    assert _no_temp_files(tmp_path)


def test_image_grey_and_uint8_numpy_and_jpeg(tmp_path):
    grey = np.arange(20, dtype=np.uint8).reshape(4, 5) * 10
    write_image(tmp_path / "g.pgm", grey)
    back = read_image(tmp_path / "g.pgm")
    assert back.shape == (1, 1, 4, 5)
    np.testing.assert_allclose(back[0, 0].numpy() * 255, grey, atol=1e-4)
    smooth = np.tile(np.linspace(0, 1, 32, dtype=np.float32), (16, 1))
    write_image(tmp_path / "s.jpg", np.stack([smooth] * 3, -1))
    assert (read_image(tmp_path / "s.jpg")[0, 0] - torch.from_numpy(smooth)).abs().max() < 0.05


def test_image_16bit_png(tmp_path):
    a = np.array([[0, 65535], [32768, 1000]], np.uint16)
    cv2.imwrite(str(tmp_path / "w.png"), a)
    np.testing.assert_allclose(read_image(tmp_path / "w.png")[0, 0].numpy(), a / 65535.0, rtol=1e-6)


def test_write_image_rejects(tmp_path):
    with pytest.raises(ValueError, match="img: expected 1 or 3 channels"):
        write_image(tmp_path / "x.png", torch.zeros(2, 4, 4))
    with pytest.raises(ValueError, match="finite"):
        write_image(tmp_path / "x.png", torch.full((1, 4, 4), float("nan")))
    with pytest.raises(ValueError, match="extension"):
        write_image(tmp_path / "x", torch.zeros(1, 4, 4))
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("cut", [10, 40, -5])
def test_truncated_png(tmp_path, cut):
    write_image(tmp_path / "im.png", torch.rand(3, 16, 16))
    data = (tmp_path / "im.png").read_bytes()
    (tmp_path / "im.png").write_bytes(data[:cut])
    with pytest.raises(FileFormatError, match=r"im\.png: truncated PNG"):
        read_image(tmp_path / "im.png")


def test_corrupt_png_crc_and_garbage(tmp_path):
    write_image(tmp_path / "im.png", torch.rand(3, 16, 16))
    data = bytearray((tmp_path / "im.png").read_bytes())
    data[60] ^= 0xFF
    (tmp_path / "im.png").write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match=r"im\.png: corrupt PNG: CRC mismatch"):
        read_image(tmp_path / "im.png")
    (tmp_path / "junk.png").write_bytes(b"hello world, not an image")
    with pytest.raises(FileFormatError, match=r"junk\.png: cannot decode"):
        read_image(tmp_path / "junk.png")


def test_pfm_windows_line_ends(tmp_path):
    (tmp_path / "w.pfm").write_bytes(b"Pf\r\n2 1\r\n-1.0\r\n" + struct.pack("<2f", 1.5, 2.5))
    np.testing.assert_array_equal(read_pfm(tmp_path / "w.pfm"), [[1.5, 2.5]])


def test_truncated_jpeg(tmp_path):
    write_image(tmp_path / "photo.jpg", torch.rand(3, 32, 32))
    data = (tmp_path / "photo.jpg").read_bytes()
    (tmp_path / "photo.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match=r"photo\.jpg: truncated JPEG"):
        read_image(tmp_path / "photo.jpg")


def test_truncated_pgm(tmp_path):
    write_image(tmp_path / "d.pgm", np.zeros((10, 10), np.uint8))
    data = (tmp_path / "d.pgm").read_bytes()
    (tmp_path / "d.pgm").write_bytes(data[:-30])
    with pytest.raises(FileFormatError, match=r"d\.pgm: truncated, expected 100 bytes of data, got 70"):
        read_image(tmp_path / "d.pgm")


# ---------------------------------------------------------------- disparity
def test_kitti_png16_roundtrip(tmp_path):
    rng = np.random.default_rng(1)
    d = rng.uniform(0, 200, (6, 9)).astype(np.float32)
    valid = rng.random((6, 9)) > 0.3
    write_disparity_png16(tmp_path / "d.png", torch.from_numpy(d)[None], torch.from_numpy(valid)[None])
    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(raw[~valid], 0)
    np.testing.assert_array_equal(raw[valid], np.clip(np.rint(d[valid] * 256), 1, None))
    back, v = read_disparity(tmp_path / "d.png")
    np.testing.assert_array_equal(v, valid)
    assert np.abs(back[valid] - d[valid]).max() <= 0.5 / 256 + 1e-6
    assert (back[~valid] == 0).all()


def test_disparity_writers_reject(tmp_path):
    with pytest.raises(ValueError, match="does not fit"):
        write_disparity_png16(tmp_path / "d.png", np.full((2, 2), 300.0))
    with pytest.raises(ValueError, match=">= 0"):
        write_disparity_png16(tmp_path / "d.png", np.full((2, 2), -1.0))
    with pytest.raises(ValueError, match=r"\.png"):
        write_disparity_png16(tmp_path / "d.pfm", np.ones((2, 2)))
    with pytest.raises(TypeError, match="valid: expected a bool"):
        write_disparity_png16(tmp_path / "d.png", np.ones((2, 2)), np.ones((2, 2)))


def test_middlebury_8bit_scaled(tmp_path):
    d = np.array([[0.0, 1.25], [10.0, 63.75]])
    valid = np.array([[False, True], [True, True]])
    for ext in ("png", "pgm"):
        write_disparity_png8(tmp_path / f"disp2.{ext}", d, valid, scale=4)
        raw = cv2.imread(str(tmp_path / f"disp2.{ext}"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(raw, [[0, 5], [40, 255]])
        back, v = read_disparity(tmp_path / f"disp2.{ext}", scale=4)
        np.testing.assert_array_equal(v, valid)
        np.testing.assert_allclose(back, d)
        with pytest.raises(ValueError, match="scale: .*8-bit"):
            read_disparity(tmp_path / f"disp2.{ext}")


def test_disparity_pfm_inf_invalid(tmp_path):
    d = np.array([[1.5, 2.0], [3.0, 4.0]], np.float32)
    valid = np.array([[True, False], [True, True]])
    write_disparity_pfm(tmp_path / "disp0GT.pfm", d, valid)
    assert np.isinf(read_pfm(tmp_path / "disp0GT.pfm")[0, 1])
    back, v = read_disparity(tmp_path / "disp0GT.pfm")
    np.testing.assert_array_equal(v, valid)
    np.testing.assert_array_equal(back, np.where(valid, d, 0))


def test_read_colour_png_as_disparity_fails(tmp_path):
    write_image(tmp_path / "c.png", torch.rand(3, 4, 4))
    with pytest.raises(FileFormatError, match=r"c\.png: expected a single-channel disparity"):
        read_disparity(tmp_path / "c.png", scale=4)


def test_real_disparities(shared_data):
    d, v = read_disparity(shared_data / "middlebury2001/tsukuba/disp3.pgm", scale=16)
    assert d.shape == (288, 384)
    assert not v[:18].any() and not v[:, :18].any() and v[18:-18, 18:-18].all()  # 18-px unknown border
    assert 4.9 < d[v].min() and d[v].max() <= 15.0
    d, v = read_disparity(shared_data / "kitti2015/training/disp_occ_0/000000_10.png")
    assert d.shape == (375, 1242) and 0.1 < v.mean() < 0.8 and 0 < d[v].max() < 256


# ---------------------------------------------------------------- PLY
def test_ply_roundtrip_and_header(tmp_path):
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(50, 3)).astype(np.float32)
    col = rng.integers(0, 256, (50, 3), dtype=np.uint8)
    write_ply(tmp_path / "cloud.ply", torch.from_numpy(pts), col)
    data = (tmp_path / "cloud.ply").read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert header.startswith(b"ply\nformat binary_little_endian 1.0\n")
    assert b"element vertex 50\n" in header
    assert b"property float x\nproperty float y\nproperty float z\n" in header
    assert b"property uchar red\nproperty uchar green\nproperty uchar blue\n" in header
    assert len(body) == 50 * 15
    x0, y0, z0, r0, g0, b0 = struct.unpack("<fffBBB", body[:15])
    assert (x0, y0, z0) == tuple(float(v) for v in pts[0]) and (r0, g0, b0) == tuple(int(v) for v in col[0])
    p2, c2 = read_ply(tmp_path / "cloud.ply")
    np.testing.assert_array_equal(p2, pts)
    np.testing.assert_array_equal(c2, col)
    write_ply(tmp_path / "nocol.ply", pts)
    p3, c3 = read_ply(tmp_path / "nocol.ply")
    np.testing.assert_array_equal(p3, pts)
    assert c3 is None


def test_ply_reads_ascii_and_big_endian_with_faces(tmp_path):
    ascii_ply = (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                 b"property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
                 b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                 b"1 2 3 10 20 30\n4 5 6 40 50 60\n3 0 1 1\n")
    (tmp_path / "a.ply").write_bytes(ascii_ply)
    p, c = read_ply(tmp_path / "a.ply")
    np.testing.assert_array_equal(p, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(c, [[10, 20, 30], [40, 50, 60]])
    big = (b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\nproperty double y\n"
           b"property double z\nend_header\n" + struct.pack(">3d", 1.5, -2.0, 7.0))
    (tmp_path / "b.ply").write_bytes(big)
    np.testing.assert_array_equal(read_ply(tmp_path / "b.ply")[0], [[1.5, -2.0, 7.0]])


def test_ply_truncated_and_bad(tmp_path):
    write_ply(tmp_path / "cloud.ply", np.zeros((10, 3)), np.zeros((10, 3), np.uint8))
    data = (tmp_path / "cloud.ply").read_bytes()
    (tmp_path / "cloud.ply").write_bytes(data[:-20])
    with pytest.raises(FileFormatError, match=r"cloud\.ply: truncated, expected 150 bytes of vertex data, got 130"):
        read_ply(tmp_path / "cloud.ply")
    (tmp_path / "x.ply").write_bytes(b"solid ascii stl")
    with pytest.raises(FileFormatError, match=r"x\.ply: not a PLY file"):
        read_ply(tmp_path / "x.ply")
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\)"):
        write_ply(tmp_path / "y.ply", np.zeros((4, 2)))
    with pytest.raises(ValueError, match="colors: expected shape"):
        write_ply(tmp_path / "y.ply", np.zeros((4, 3)), np.zeros((3, 3), np.uint8))
    with pytest.raises(ValueError, match="finite"):
        write_ply(tmp_path / "y.ply", np.full((4, 3), np.nan))
    assert not (tmp_path / "y.ply").exists()


def test_ply_readable_by_opencv_viz_free_parser(tmp_path):
    # an independent reader: numpy structured dtype straight from the documented layout
    pts = np.array([[0.5, 1.5, 2.5]], np.float32)
    write_ply(tmp_path / "one.ply", pts, np.array([[1, 2, 3]], np.uint8))
    body = (tmp_path / "one.ply").read_bytes().split(b"end_header\n")[1]
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    assert rec["x"][0] == 0.5 and rec["z"][0] == 2.5 and rec["b"][0] == 3


def _exif_orientation_segment(orientation: int) -> bytes:
    """A minimal APP1/Exif segment with one IFD entry: Orientation (0x0112, SHORT) = ``orientation``."""
    import struct

    tiff = b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", 1)
    tiff += struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack("<I", 0)
    body = b"Exif\x00\x00" + tiff
    return b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body


def test_jpeg_with_data_after_the_end_marker(tmp_path):
    # phones append vendor blocks (and MPF previews) after FFD9; OpenCV decodes such files
    img = torch.rand(3, 24, 40, generator=torch.Generator().manual_seed(0))
    write_image(tmp_path / "phone.jpg", img)
    plain = read_image(tmp_path / "phone.jpg")
    data = (tmp_path / "phone.jpg").read_bytes() + b"\x00" * 50 + b"vendor trailer " * 20
    (tmp_path / "phone.jpg").write_bytes(data)
    torch.testing.assert_close(read_image(tmp_path / "phone.jpg"), plain)


def test_jpeg_exif_orientation_is_honoured(tmp_path):
    img = torch.zeros(3, 20, 30)
    img[:, :5, :] = 1.0  # a bright band at the top of the stored image
    write_image(tmp_path / "a.jpg", img)
    data = (tmp_path / "a.jpg").read_bytes()
    (tmp_path / "rot.jpg").write_bytes(data[:2] + _exif_orientation_segment(6) + data[2:])  # 6 = rotate 90 cw
    rot = read_image(tmp_path / "rot.jpg")
    assert rot.shape[-2:] == (30, 20)  # shown upright: width and height swapped
    assert float(rot[0, :, :, -5:].mean()) > 0.8 and float(rot[0, :, :, :5].mean()) < 0.2  # band now at the right


def test_truncated_jpeg_inside_a_segment(tmp_path):
    write_image(tmp_path / "photo.jpg", torch.rand(3, 32, 32))
    data = (tmp_path / "photo.jpg").read_bytes()
    (tmp_path / "photo.jpg").write_bytes(data[:30])  # inside the header segments
    with pytest.raises(FileFormatError, match=r"photo\.jpg: truncated"):
        read_image(tmp_path / "photo.jpg")


def test_an_image_header_beyond_opencvs_limits_is_a_file_error(tmp_path):
    """A PNG whose header claims 200000 x 200000 pixels: a one-line file error, not cv2.error."""
    import struct
    import zlib

    from stereonet.io import FileFormatError, read_image

    ihdr = struct.pack(">IIBBBBB", 200000, 200000, 8, 0, 0, 0, 0)
    chunk = lambda kind, data: (struct.pack(">I", len(data)) + kind + data
                                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    (tmp_path / "huge.png").write_bytes(png)
    with pytest.raises(FileFormatError, match="huge.png"):
        read_image(tmp_path / "huge.png")


def test_read_disparity_scale_and_calibration_size_are_checked(tmp_path):
    from stereonet.io import read_disparity
    from stereonet.types import Calibration

    cv2.imwrite(str(tmp_path / "d.png"), np.full((4, 6), 40, np.uint8))
    assert read_disparity(tmp_path / "d.png", scale=np.float32(4))[0][0, 0] == 10.0  # numpy scalars are numbers
    for scale in ("16", float("nan"), 0):
        with pytest.raises(StereoInputError, match="scale"):
            read_disparity(tmp_path / "d.png", scale=scale)
    with pytest.raises(StereoInputError, match="image_size"):
        Calibration(torch.eye(3), torch.eye(3), torch.eye(3), torch.tensor([1.0, 0, 0]), image_size=(64,))
