"""The LIBERO image pipeline against TensorFlow's outputs (``openvla_reference/preprocess_cases.npz``).

Measured deviation of the numpy pipeline from the TF 2.15 reference, per stage, on all 3 images:
JPEG round trip (Pillow's encoder + simplejpeg's fast-IDCT decoder), lanczos3 resize, centre crop and the
whole chain are bit-identical (max 0 grey levels). For comparison, Pillow's JPEG decoder is off by up to 17
levels and Pillow's LANCZOS resize by up to 9.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.openvla import preprocessing
from vlaprobe.policies.openvla.jpeg import jpeg_encode, jpeg_round_trip

MAX_GREY_LEVEL_DIFF = 0
"""Measured: the numpy pipeline reproduces every TF stage exactly."""
MAX_CROP_FLOAT_DIFF = 0.0
"""Measured on image 0: the float32 crop equals TF's bit for bit."""


@pytest.fixture(scope="module")
def npz(reference: Path):
    return np.load(reference / "preprocess_cases.npz")


def _max_diff(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.abs(a.astype(np.int64) - b.astype(np.int64)).max())


@pytest.mark.parametrize("i", [0, 1, 2])
def test_each_stage_matches_tensorflow(npz, i):
    rotated = np.ascontiguousarray(npz["input_256"][i][::-1, ::-1])
    assert _max_diff(jpeg_round_trip(rotated), npz["jpeg_decoded_256"][i]) <= MAX_GREY_LEVEL_DIFF
    resized = preprocessing.resize_lanczos3(npz["jpeg_decoded_256"][i], 224)
    assert _max_diff(resized, npz["after_resize_224"][i]) <= MAX_GREY_LEVEL_DIFF
    cropped = preprocessing.center_crop_resize(npz["after_resize_224"][i])
    assert _max_diff(cropped, npz["after_crop_224"][i]) <= MAX_GREY_LEVEL_DIFF
    full = preprocessing.libero_image(npz["input_256"][i], 224, center_crop=True)
    assert _max_diff(full, npz["after_crop_224"][i]) <= MAX_GREY_LEVEL_DIFF
    no_crop = preprocessing.libero_image(npz["input_256"][i], 224, center_crop=False)
    assert _max_diff(no_crop, npz["after_resize_224"][i]) <= MAX_GREY_LEVEL_DIFF


def test_pillow_decoder_is_not_enough(npz):
    """Why the decoder is simplejpeg's: Pillow's accurate IDCT is far from TF's fast one."""
    decoded = np.asarray(Image.open(io.BytesIO(npz["jpeg_bytes_1"].tobytes())).convert("RGB"))
    assert _max_diff(decoded, npz["jpeg_decoded_256"][1]) > 5


def _dqt(data: bytes) -> dict[int, bytes]:
    """The quantisation tables (DQT segments, zigzag order) of a JPEG file, by table id."""
    tables, pos = {}, 2
    while data[pos : pos + 2] != b"\xff\xda":  # walk the segments up to the start of scan
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if data[pos + 1] == 0xDB:
            seg = data[pos + 4 : pos + 2 + length]
            for k in range(0, len(seg), 65):
                tables[seg[k] & 15] = seg[k + 1 : k + 65]
        pos += 2 + length
    return tables


def test_encoder_writes_tensorflows_tables_and_coefficients(npz):
    """Pillow's quality-95 encoding has the DQT tables TF wrote into the reference JPEG, and its decode
    through the fast IDCT is TF's decode of TF's own bytes."""
    rotated = np.ascontiguousarray(npz["input_256"][0][::-1, ::-1])
    ours = jpeg_encode(rotated)
    reference = npz["jpeg_bytes_0"].tobytes()
    assert _dqt(ours) == _dqt(reference) and len(_dqt(ours)) == 2
    import simplejpeg

    tf_decoded = simplejpeg.decode_jpeg(reference, colorspace="RGB", fastdct=True)
    np.testing.assert_array_equal(tf_decoded, npz["jpeg_decoded_256"][0])


def test_crop_float_values(npz):
    """The float crop before the uint8 conversion (the reference's debug aid for image 0)."""
    out = preprocessing.center_crop_float(npz["after_resize_224"][0])
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, npz["crop_float32_224_img0"], rtol=0, atol=MAX_CROP_FLOAT_DIFF)


@pytest.mark.parametrize("shape", [(9, 9), (17, 23), (131, 77)])
def test_odd_sized_frames_are_padded_like_libjpeg(shape):
    """Frames whose sides are not multiples of 16 (partial blocks and MCUs): on a smooth image the only
    difference from Pillow's codec is the IDCT (measured max 4 levels at every size, edges included);
    wrong edge padding would show as large errors along the last rows and columns."""
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]]
    frame = np.stack([60 + 2 * x, 80 + 3 * y, 100 + x + y], axis=-1).clip(0, 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(frame).save(buf, format="JPEG", quality=95)
    pil = np.asarray(Image.open(buf).convert("RGB"))
    assert _max_diff(jpeg_round_trip(frame), pil) <= 5
    out = preprocessing.libero_image(frame, 224)
    assert out.shape == (224, 224, 3) and out.dtype == np.uint8


def test_bad_images_are_one_line_errors():
    with pytest.raises(VlaprobeError, match="uint8"):
        preprocessing.libero_image(np.zeros((256, 256, 3), dtype=np.float32))
    with pytest.raises(VlaprobeError, match=r"\(H, W, 3\)"):
        preprocessing.libero_image(np.zeros((256, 256), dtype=np.uint8))
    with pytest.raises(VlaprobeError, match="backend"):
        preprocessing.libero_image(np.zeros((256, 256, 3), dtype=np.uint8), backend="cv2")  # type: ignore[arg-type]


def test_tf_backend(monkeypatch, npz):
    """The optional TensorFlow path: the reference itself when installed, else a one-line error."""
    try:
        import tensorflow  # noqa: F401
    except ImportError:
        monkeypatch.setitem(sys.modules, "tensorflow", None)
        with pytest.raises(VlaprobeError, match=r"vlaprobe\[tf\]") as err:
            preprocessing.libero_image(npz["input_256"][0], backend="tf")
        assert "\n" not in str(err.value)
        return
    out = preprocessing.libero_image(npz["input_256"][0], backend="tf")
    np.testing.assert_array_equal(out, npz["after_crop_224"][0])
    rng = np.random.default_rng(1)
    for shape in [(256, 256, 3), (200, 300, 3), (131, 77, 3)]:  # measured: 80 such frames, all identical
        frame = rng.integers(0, 256, shape, dtype=np.uint8)
        np.testing.assert_array_equal(
            preprocessing.libero_image(frame), preprocessing.libero_image(frame, backend="tf")
        )


def test_resize_without_a_c_sinf(monkeypatch, npz):
    """Where no C math library loads, the correctly rounded sine stands in for TF's ``sinf``: weights move
    by at most 1 ulp (measured: still bit-identical on the reference images; a rounding flip can cost 1)."""
    monkeypatch.setattr(preprocessing, "_libm_sinf", lambda: None)
    preprocessing._spans.cache_clear()
    try:
        for i in range(3):
            out = preprocessing.resize_lanczos3(npz["jpeg_decoded_256"][i], 224)
            assert _max_diff(out, npz["after_resize_224"][i]) <= 1
    finally:
        preprocessing._spans.cache_clear()
