"""OpenVLA's LIBERO image preprocessing, from the raw agentview render to the model's pixel values.

What OpenVLA's ``run_libero_eval.py`` does to each frame, in order (every step reproduced here):

1. ``get_libero_image``: rotate the 256×256 ``agentview_image`` by 180° (``img[::-1, ::-1]``).
2. ``resize_image``: JPEG-encode (quality 95, 4:2:0) and decode right back, as the RLDS dataset builder did
   to the training frames; TensorFlow decodes with libjpeg-turbo's fast integer IDCT.
3. ``resize_image``: ``tf.image.resize(..., 224, method="lanczos3", antialias=True)``, round half to even,
   clip to [0, 255], uint8.
4. ``get_vla_action(center_crop=True)`` (the LIBERO fine-tunes were trained with random-crop augmentation):
   scale to [0, 1] (× 1/255), ``tf.image.crop_and_resize`` of the centred box holding 0.9 of the area
   (side √0.9), bilinear back to 224×224, clip to [0, 1], back to uint8 by ``floor(x · 255.5)``.
5. The HF processor: for a 224×224 image its bicubic resize and centre crop are identities; each backbone
   gets its own normalisation, DINOv2 with the bf16-rounded ImageNet constants the released processor
   stores, SigLIP with 0.5 / 0.5; the 6 channels are stacked DINOv2 first.

The default backend ("numpy") reproduces steps 2–4 with TensorFlow's exact arithmetic (Pillow's encoder and
libjpeg-turbo's fast IDCT through simplejpeg for the JPEG, float32 numpy kernels for the two resamplers). The "tf" backend runs TensorFlow itself
(``pip install vlaprobe[tf]``) and is the reference.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np

from vlaprobe.configs.policy import Preprocessing
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.openvla.jpeg import jpeg_round_trip

CROP_SCALE = 0.9
"""Area fraction of OpenVLA's LIBERO centre crop."""

DINOV2_MEAN = (0.484375, 0.455078125, 0.40625)
"""ImageNet mean as the released OpenVLA processor stores it: rounded to bfloat16 by the converter."""
DINOV2_STD = (0.228515625, 0.2236328125, 0.224609375)
"""ImageNet std, bf16-rounded likewise."""
SIGLIP_MEAN = (0.5, 0.5, 0.5)
SIGLIP_STD = (0.5, 0.5, 0.5)


@lru_cache(maxsize=1)
def _libm_sinf() -> Callable[[float], float] | None:
    """The C library's ``sinf``, which TensorFlow's kernel calls. glibc's is not correctly rounded (it
    differs from the rounded exact sine on ~1% of arguments), so matching TF's weights bit for bit needs
    the same function. None where no C math library can be loaded."""
    import ctypes
    import ctypes.util

    try:
        fn = ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6").sinf
    except (OSError, AttributeError):
        return None
    fn.restype, fn.argtypes = ctypes.c_float, [ctypes.c_float]
    return fn


def _sinf(a: np.ndarray) -> np.ndarray:
    sinf = _libm_sinf()
    if sinf is None:  # the correctly rounded sine: within 1 ulp of any libm's
        return np.sin(a.astype(np.float64)).astype(np.float32)
    return np.array([sinf(float(v)) for v in a.ravel()], dtype=np.float32).reshape(a.shape)


def _lanczos3(x: np.ndarray) -> np.ndarray:
    """TensorFlow's ``LanczosKernelFunc(3)``, float32 operation by operation."""
    pi = np.float32(3.14159265359)
    r = np.float32(3.0)
    x = np.abs(x).astype(np.float32)
    s1 = _sinf((pi * x).astype(np.float32))
    s2 = _sinf((pi * x / r).astype(np.float32))
    with np.errstate(divide="ignore", invalid="ignore"):
        v = r * s1 * s2 / (pi * pi * x * x)
    small = np.where(x <= np.float32(1e-3), np.float32(1), v)
    return np.where(x > r, np.float32(0), small).astype(np.float32)


@lru_cache(maxsize=16)
def _spans(out_size: int, in_size: int) -> tuple[np.ndarray, np.ndarray]:
    """``ComputeSpansCore`` of TF's scale_and_translate (lanczos3, antialias, no translation).

    Returns (starts (out,), weights (out, span)) in float32, zero-padded where a span is short.
    """
    scale = np.float32(np.float32(out_size) / np.float32(in_size))
    inv_scale = np.float32(1.0 / float(scale))
    kernel_scale = max(inv_scale, np.float32(1.0))
    radius = np.float32(3.0) * kernel_scale
    span = min(2 * int(np.ceil(radius)) + 1, in_size)
    starts = np.zeros(out_size, dtype=np.int64)
    weights = np.zeros((out_size, span), dtype=np.float32)
    inv_kernel_scale = np.float32(1.0) / kernel_scale
    for x in range(out_size):
        sample = np.float32(np.float32(x) + np.float32(0.5)) * inv_scale
        if sample < 0 or sample > in_size:
            continue
        start = int(np.clip(np.ceil(sample - radius - np.float32(0.5)), 0, in_size - 1))
        end = int(np.clip(np.floor(sample + radius - np.float32(0.5)), 0, in_size - 1)) + 1
        pos = (np.arange(start, end, dtype=np.float32) + np.float32(0.5) - sample) * inv_kernel_scale
        w = _lanczos3(pos)
        total = np.float32(0)
        for v in w:  # sequential float32 sum, as TF accumulates
            total = np.float32(total + v)
        if abs(total) >= 1000 * np.finfo(np.float32).tiny:
            weights[x, : end - start] = w * (np.float32(1) / total)
        starts[x] = start
    starts.flags.writeable = weights.flags.writeable = False  # cached: shared between calls
    return starts, weights


def _gather(image: np.ndarray, starts: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    """Weighted sum over spans along ``axis`` (0 = rows, 1 = columns), accumulated in span order."""
    in_size = image.shape[axis]
    src = np.ascontiguousarray(np.moveaxis(image, axis, 0))
    out = np.zeros((len(starts), *src.shape[1:]), dtype=np.float32)
    term = np.empty_like(out)
    shape = (-1, *([1] * (src.ndim - 1)))
    for j in range(weights.shape[1]):
        idx = np.minimum(starts + j, in_size - 1)  # past the span the weight is 0
        np.multiply(weights[:, j].reshape(shape), np.take(src, idx, axis=0), out=term)
        out += term
    return np.moveaxis(out, 0, axis)


def resize_lanczos3(image: np.ndarray, size: int) -> np.ndarray:
    """``tf.image.resize(image, (size, size), "lanczos3", antialias=True)`` → rounded, clipped uint8."""
    h, w = image.shape[:2]
    rows = _gather(image.astype(np.float32), *_spans(size, h), axis=0)
    out = _gather(rows, *_spans(size, w), axis=1)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)  # rint rounds half to even, like tf.round


def center_crop_float(image: np.ndarray, crop_scale: float = CROP_SCALE) -> np.ndarray:
    """OpenVLA's ``crop_and_resize`` in float32: the uint8 image × 1/255, centre box of ``crop_scale`` of the
    area (side √crop_scale, corners computed in float32), bilinear back to the input size as TF samples it
    (``y = y1·(H−1) + i·(y2−y1)·(H−1)/(H−1)``, lerp along x then y)."""
    h, w = image.shape[:2]
    img = image.astype(np.float32) * np.float32(1.0 / 255.0)
    side = np.clip(np.sqrt(np.float32(crop_scale)), np.float32(0), np.float32(1))
    lo = (np.float32(1) - side) / np.float32(2)
    hi = lo + side

    def coords(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        step = np.float32((hi - lo) * np.float32(n - 1) / np.float32(n - 1))
        pos = lo * np.float32(n - 1) + np.arange(n, dtype=np.float32) * step
        low = np.floor(pos).astype(np.int64)
        return low, np.ceil(pos).astype(np.int64), (pos - low.astype(np.float32)).astype(np.float32)

    top_i, bot_i, y_lerp = coords(h)
    left_i, right_i, x_lerp = coords(w)
    # Lerp along x over whole rows first, then pick the two rows for each output row: the same float32
    # operations on the same operands as interpolating each of the four corners per output pixel.
    left = np.take(img, left_i, axis=1)
    across = left + (np.take(img, right_i, axis=1) - left) * x_lerp[None, :, None]
    top = across[top_i]
    return top + (across[bot_i] - top) * y_lerp[:, None, None]


def center_crop_resize(image: np.ndarray, crop_scale: float = CROP_SCALE) -> np.ndarray:
    """:func:`center_crop_float`, clipped to [0, 1] and converted back to uint8 as TF's saturating
    ``convert_image_dtype`` does: ``floor(x · 255.5)``."""
    crop = center_crop_float(image, crop_scale)
    return (np.clip(crop, 0, 1) * np.float32(255.5)).astype(np.uint8)


def _libero_image_tf(raw: np.ndarray, size: int, center_crop: bool) -> np.ndarray:
    """The same steps run by TensorFlow itself (the optional ``tf`` extra)."""
    try:
        import tensorflow as tf
    except ImportError:
        raise VlaprobeError(
            "preprocessing backend 'tf' needs TensorFlow; pip install 'vlaprobe[tf]' or use the 'numpy' backend"
        ) from None
    img = tf.image.encode_jpeg(np.ascontiguousarray(raw[::-1, ::-1]))
    img = tf.io.decode_image(img, expand_animations=False, dtype=tf.uint8)
    img = tf.image.resize(img, (size, size), method="lanczos3", antialias=True)
    img = tf.cast(tf.clip_by_value(tf.round(img), 0, 255), tf.uint8)
    if center_crop:
        x = tf.image.convert_image_dtype(img, tf.float32)[None]
        side = tf.reshape(tf.clip_by_value(tf.sqrt(CROP_SCALE), 0, 1), (1,))
        off = (1 - side) / 2
        boxes = tf.stack([off, off, off + side, off + side], axis=1)
        x = tf.image.crop_and_resize(x, boxes, tf.range(1), (size, size))[0]
        img = tf.image.convert_image_dtype(tf.clip_by_value(x, 0, 1), tf.uint8, saturate=True)
    return img.numpy()


def libero_image(
    raw: np.ndarray, size: int = 224, center_crop: bool = True, backend: Preprocessing = "numpy"
) -> np.ndarray:
    """The raw LIBERO agentview render (H, W, 3) uint8, still upside down → the (size, size, 3) uint8 image
    OpenVLA's LIBERO evaluation hands to the processor."""
    if not (isinstance(raw, np.ndarray) and raw.ndim == 3 and raw.shape[2] == 3 and raw.dtype == np.uint8):
        got = f"{raw.shape} {raw.dtype}" if isinstance(raw, np.ndarray) else type(raw).__name__
        raise VlaprobeError(
            f"policy image must be an (H, W, 3) uint8 array, got {got}; pass obs['agentview_image']"
        )
    if backend == "tf":
        return _libero_image_tf(raw, size, center_crop)
    if backend != "numpy":
        raise VlaprobeError(f"unknown preprocessing backend {backend!r}; use 'numpy' or 'tf'")
    img = jpeg_round_trip(np.ascontiguousarray(raw[::-1, ::-1]))
    img = resize_lanczos3(img, size)
    return center_crop_resize(img) if center_crop else img


def pixel_values(
    image: np.ndarray,
    means: tuple[tuple[float, ...], ...] = (DINOV2_MEAN, SIGLIP_MEAN),
    stds: tuple[tuple[float, ...], ...] = (DINOV2_STD, SIGLIP_STD),
) -> np.ndarray:
    """(224, 224, 3) uint8 → (3·len(means), 224, 224) float32: ``((u8 / 255) − mean) / std`` per backbone,
    in float32 and in that order, as torchvision's ToTensor + Normalize compute it."""
    x = np.ascontiguousarray(image.transpose(2, 0, 1)).astype(np.float32) / np.float32(255)
    chans = []
    for mean, std in zip(means, stds, strict=True):
        m = np.asarray(mean, dtype=np.float32)[:, None, None]
        s = np.asarray(std, dtype=np.float32)[:, None, None]
        chans.append((x - m) / s)
    return np.concatenate(chans, axis=0)
