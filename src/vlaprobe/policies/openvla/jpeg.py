"""The JPEG round trip of OpenVLA's LIBERO evaluation, in integer numpy, bit-exact with TensorFlow.

OpenVLA's ``resize_image`` encodes the frame with ``tf.image.encode_jpeg`` (quality 95, 4:2:0) and decodes
it right back with ``tf.io.decode_image``. TensorFlow's decoder uses libjpeg-turbo's *fast integer* IDCT
(``INTEGER_FAST``); Pillow and OpenCV decode with the accurate one, up to 17 grey levels away. No Python
package exposes the fast IDCT, so this module recomputes the round trip from libjpeg's published integer
arithmetic: RGB→YCbCr, 2×2 chroma downsampling, accurate forward DCT, quantisation (the encoder side, which
Pillow's encoder reproduces byte for byte), then dequantisation with the AA&N multipliers, the fast IDCT,
"fancy" triangular chroma upsampling and YCbCr→RGB. No entropy coding is needed: the quantised
coefficients are all the decoder sees. Everything is vectorised over the 8×8 blocks.
"""

from __future__ import annotations

import numpy as np

_LUMA_QT = np.array(
    [16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55,
     14, 13, 16, 24, 40, 57, 69, 56, 14, 17, 22, 29, 51, 87, 80, 62,
     18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
     49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99],
    dtype=np.int64,
)  # fmt: skip
"""JPEG Annex K luminance table, natural (row-major) order."""

_CHROMA_QT = np.array(
    [17, 18, 24, 47] + [99] * 4 + [18, 21, 26, 66] + [99] * 4 + [24, 26, 56] + [99] * 5
    + [47, 66] + [99] * 6 + [99] * 32,
    dtype=np.int64,
)  # fmt: skip
"""JPEG Annex K chrominance table, natural order."""

_AAN_SCALES = np.array(
    [16384, 22725, 21407, 19266, 16384, 12873, 8867, 4520,
     22725, 31521, 29692, 26722, 22725, 17855, 12299, 6270,
     21407, 29692, 27969, 25172, 21407, 16819, 11585, 5906,
     19266, 26722, 25172, 22654, 19266, 15137, 10426, 5315,
     16384, 22725, 21407, 19266, 16384, 12873, 8867, 4520,
     12873, 17855, 16819, 15137, 12873, 10114, 6967, 3552,
     8867, 12299, 11585, 10426, 8867, 6967, 4799, 2446,
     4520, 6270, 5906, 5315, 4520, 3552, 2446, 1247],
    dtype=np.int64,
)  # fmt: skip
"""cos(k·π/16)·√2 row×column scale factors of the AA&N IDCT, scaled by 2**14."""


def quant_tables(quality: int = 95) -> tuple[np.ndarray, np.ndarray]:
    """libjpeg's ``jpeg_set_quality(quality, force_baseline=TRUE)`` tables as (8, 8) int arrays."""
    quality = min(max(quality, 1), 100)
    scale = 5000 // quality if quality < 50 else 200 - 2 * quality
    out = []
    for base in (_LUMA_QT, _CHROMA_QT):
        q = np.clip((base * scale + 50) // 100, 1, 255)
        out.append(q.reshape(8, 8))
    return out[0], out[1]


# --- encoder side -------------------------------------------------------------------------------------------

_S16 = 1 << 16


def _fix16(x: float) -> int:
    return int(x * _S16 + 0.5)


def _rgb_to_ycc(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """jccolor.c ``rgb_ycc_convert``: 16-bit fixed point, Y rounded, Cb/Cr rounded with 0.5-ε."""
    r, g, b = (rgb[..., i].astype(np.int32) for i in range(3))  # sums stay below 2**25
    half = 1 << 15
    y = (_fix16(0.29900) * r + _fix16(0.58700) * g + _fix16(0.11400) * b + half) >> 16
    offset = (128 << 16) + half - 1
    cb = (-_fix16(0.16874) * r - _fix16(0.33126) * g + _fix16(0.5) * b + offset) >> 16
    cr = (_fix16(0.5) * r - _fix16(0.41869) * g - _fix16(0.08131) * b + offset) >> 16
    return y, cb, cr


def _pad_edge(plane: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Replicate the last row/column up to (rows, cols), as libjpeg pads partial blocks."""
    return np.pad(plane, ((0, rows - plane.shape[0]), (0, cols - plane.shape[1])), mode="edge")


def _ceil(a: int, b: int) -> int:
    return -(-a // b)


def _downsample_h2v2(plane: np.ndarray) -> np.ndarray:
    """jcsample.c ``h2v2_downsample``: 2×2 box average with alternating rounding bias 1, 2, 1, 2, …"""
    s = plane[0::2, 0::2] + plane[0::2, 1::2] + plane[1::2, 0::2] + plane[1::2, 1::2]
    bias = np.where(np.arange(s.shape[1]) % 2 == 0, 1, 2)
    return (s + bias) >> 2


def _blocks(plane: np.ndarray) -> np.ndarray:
    """(H, W) with H, W multiples of 8 → (H/8, W/8, 8, 8)."""
    h, w = plane.shape
    return plane.reshape(h // 8, 8, w // 8, 8).swapaxes(1, 2)


def _unblocks(blocks: np.ndarray) -> np.ndarray:
    by, bx = blocks.shape[:2]
    return blocks.swapaxes(1, 2).reshape(by * 8, bx * 8)


def _descale(x: np.ndarray, n: int) -> np.ndarray:
    return (x + (1 << (n - 1))) >> n


def _fdct_1d(d: list[np.ndarray], shift_even: int, shift_odd: int, scale_dc: bool) -> list[np.ndarray]:
    """One pass of jfdctint.c ``jpeg_fdct_islow`` (Loeffler–Ligtenberg–Moschytz), 13-bit constants."""
    t0, t7 = d[0] + d[7], d[0] - d[7]
    t1, t6 = d[1] + d[6], d[1] - d[6]
    t2, t5 = d[2] + d[5], d[2] - d[5]
    t3, t4 = d[3] + d[4], d[3] - d[4]
    t10, t13, t11, t12 = t0 + t3, t0 - t3, t1 + t2, t1 - t2
    out: list[np.ndarray] = [np.empty(0)] * 8
    if scale_dc:  # pass 1: scale up by 2**PASS1_BITS
        out[0], out[4] = (t10 + t11) << 2, (t10 - t11) << 2
    else:  # pass 2: remove it
        out[0], out[4] = _descale(t10 + t11, 2), _descale(t10 - t11, 2)
    z1 = (t12 + t13) * 4433
    out[2] = _descale(z1 + t13 * 6270, shift_even)
    out[6] = _descale(z1 - t12 * 15137, shift_even)
    z1, z2, z3, z4 = t4 + t7, t5 + t6, t4 + t6, t5 + t7
    z5 = (z3 + z4) * 9633
    t4, t5, t6, t7 = t4 * 2446, t5 * 16819, t6 * 25172, t7 * 12299
    z1, z2 = z1 * -7373, z2 * -20995
    z3, z4 = z3 * -16069 + z5, z4 * -3196 + z5
    out[7] = _descale(t4 + z1 + z3, shift_odd)
    out[5] = _descale(t5 + z2 + z4, shift_odd)
    out[3] = _descale(t6 + z2 + z3, shift_odd)
    out[1] = _descale(t7 + z1 + z4, shift_odd)
    return out


def _fdct_islow(blocks: np.ndarray) -> np.ndarray:
    """Forward DCT of level-shifted samples (..., 8, 8); result scaled by 8 like libjpeg's."""
    blocks = blocks.astype(np.int64)  # second-pass sums reach 2**30.5: too close to int32's limit
    rows = _fdct_1d([blocks[..., i] for i in range(8)], 13 - 2, 13 - 2, scale_dc=True)
    tmp = np.stack(rows, axis=-1)
    cols = _fdct_1d([tmp[..., i, :] for i in range(8)], 13 + 2, 13 + 2, scale_dc=False)
    return np.stack(cols, axis=-2)


def _quantize(coefs: np.ndarray, qtable: np.ndarray) -> np.ndarray:
    """jcdctmgr.c ``quantize`` with ``compute_reciprocal`` divisors (divisor = 8·q for the islow FDCT)."""
    divisor = qtable * 8
    b = np.floor(np.log2(divisor)).astype(np.int64)
    r = 16 + b
    fq = (np.int64(1) << r) // divisor
    fr = (np.int64(1) << r) % divisor
    c = divisor // 2
    pow2 = fr == 0
    fq = np.where(pow2, fq >> 1, fq)
    r = np.where(pow2, r - 1, r)
    c = np.where(~pow2 & (fr <= divisor // 2), c + 1, c)
    fq = np.where(~pow2 & (fr > divisor // 2), fq + 1, fq)
    mag = ((np.abs(coefs) + c) * fq) >> r
    return np.where(coefs < 0, -mag, mag).astype(np.int32)  # the rest of the decoder runs in int32


# --- decoder side -------------------------------------------------------------------------------------------


def _idct_ifast_1d(d: list[np.ndarray]) -> list[np.ndarray]:
    """One pass of jidctfst.c ``jpeg_idct_ifast`` (AA&N), 8-bit constants, truncating multiplies."""

    def mul(x: np.ndarray, c: int) -> np.ndarray:
        return (x * c) >> 8

    t10, t11 = d[0] + d[4], d[0] - d[4]
    t13 = d[2] + d[6]
    t12 = mul(d[2] - d[6], 362) - t13
    t0, t3, t1, t2 = t10 + t13, t10 - t13, t11 + t12, t11 - t12
    z13, z10 = d[5] + d[3], d[5] - d[3]
    z11, z12 = d[1] + d[7], d[1] - d[7]
    t7 = z11 + z13
    t11 = mul(z11 - z13, 362)
    z5 = mul(z10 + z12, 473)
    t10 = mul(z12, 277) - z5
    t12 = mul(z10, -669) + z5
    t6 = t12 - t7
    t5 = t11 - t6
    t4 = t10 + t5
    return [t0 + t7, t1 + t6, t2 + t5, t3 - t4, t3 + t4, t2 - t5, t1 - t6, t0 - t7]


def _idct_ifast(coefs: np.ndarray, qtable: np.ndarray) -> np.ndarray:
    """Dequantise and inverse-transform quantised blocks (..., 8, 8) → samples 0..255 (int32)."""
    mult = ((qtable.reshape(-1) * _AAN_SCALES + (1 << 11)) >> 12).reshape(8, 8).astype(np.int32)
    deq = coefs * mult
    cols = _idct_ifast_1d([deq[..., k, :] for k in range(8)])  # pass 1 runs down the columns
    ws = np.stack(cols, axis=-2)
    rows = _idct_ifast_1d([ws[..., k] for k in range(8)])
    out = np.stack(rows, axis=-1) >> 5  # descale by 8 and PASS1_BITS, no rounding (IFAST)
    out = (out + 512) % 1024 - 512  # libjpeg's range-limit table wraps at ±512 ...
    return np.clip(out + 128, 0, 255)  # ... and clamps inside


def _upsample_h2v2_fancy(plane: np.ndarray, out_h: int, out_w: int) -> np.ndarray:
    """jdsample.c ``h2v2_fancy_upsample``: triangle filter, 9/16 3/16 3/16 1/16, edges replicated."""
    up = np.concatenate([plane[:1], plane[:-1]], axis=0)
    down = np.concatenate([plane[1:], plane[-1:]], axis=0)
    h, w = plane.shape
    result = np.empty((2 * h, 2 * w), dtype=plane.dtype)
    for v, other in ((0, up), (1, down)):
        colsum = plane * 3 + other
        last = np.concatenate([colsum[:, :1], colsum[:, :-1]], axis=1)
        nxt = np.concatenate([colsum[:, 1:], colsum[:, -1:]], axis=1)
        even = (colsum * 3 + last + 8) >> 4
        odd = (colsum * 3 + nxt + 7) >> 4
        even[:, 0] = (colsum[:, 0] * 4 + 8) >> 4
        odd[:, -1] = (colsum[:, -1] * 4 + 7) >> 4
        result[v::2, 0::2] = even
        result[v::2, 1::2] = odd
    return result[:out_h, :out_w]


def _ycc_to_rgb(y: np.ndarray, cb: np.ndarray, cr: np.ndarray) -> np.ndarray:
    """jdcolor.c ``ycc_rgb_convert`` with its rounded lookup tables."""
    half = 1 << 15
    x_cb, x_cr = cb - 128, cr - 128
    r = y + ((_fix16(1.40200) * x_cr + half) >> 16)
    b = y + ((_fix16(1.77200) * x_cb + half) >> 16)
    g = y + ((-_fix16(0.34414) * x_cb + half - _fix16(0.71414) * x_cr) >> 16)
    return np.clip(np.stack([r, g, b], axis=-1), 0, 255).astype(np.uint8)


def jpeg_round_trip(rgb: np.ndarray, quality: int = 95) -> np.ndarray:
    """Encode ``rgb`` (H, W, 3) uint8 as baseline 4:2:0 JPEG and decode it with the fast integer IDCT.

    Bit-exact with ``tf.io.decode_image(tf.image.encode_jpeg(rgb))`` under TensorFlow's defaults
    (checked against the reference in ``openvla_reference/preprocess_cases.npz``).
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    h, w = rgb.shape[:2]
    y, cb, cr = _rgb_to_ycc(rgb)
    luma_q, chroma_q = quant_tables(quality)

    y_full = _pad_edge(y, _ceil(h, 8) * 8, _ceil(w, 8) * 8)
    y_dec = _unblocks(_idct_ifast(_quantize(_fdct_islow(_blocks(y_full - 128)), luma_q), luma_q))[:h, :w]

    ch, cw = _ceil(h, 2), _ceil(w, 2)  # downsampled size the decoder upsamples from
    planes = []
    for plane in (cb, cr):
        wide = _pad_edge(plane, 2 * ch, _ceil(w, 16) * 16)  # right edge to the MCU, bottom to even rows
        small = _pad_edge(_downsample_h2v2(wide), _ceil(ch, 8) * 8, _ceil(w, 16) * 8)
        dec = _unblocks(_idct_ifast(_quantize(_fdct_islow(_blocks(small - 128)), chroma_q), chroma_q))
        planes.append(_upsample_h2v2_fancy(dec[:ch, :cw], h, w))
    return _ycc_to_rgb(y_dec, planes[0], planes[1])
