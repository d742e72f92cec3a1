"""OpenVLA's training-time image augmentation on a batch of [0, 1] images, driven by a numpy generator.

What OpenVLA's RLDS loader applies with ``image_aug=True``, in its order: a random square crop holding
``crop_scale`` of the area, resized back to the input size (bilinear); brightness + U(−0.2, 0.2); contrast
× U(0.8, 1.2) about each channel's mean; saturation × U(0.8, 1.2) about the grey value. OpenVLA's hue shift
(±0.05) is left out. Every draw comes from the generator, so a seed fixes the augmentation.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

LUMA = (0.2989, 0.587, 0.114)
"""Grey value weights (TensorFlow's ``rgb_to_grayscale``), used by the saturation jitter."""


def random_crop(x: torch.Tensor, rng: np.random.Generator, crop_scale: float) -> torch.Tensor:
    """(B, 3, S, S) → a random crop of side √crop_scale per image, resampled bilinearly to S×S."""
    b = x.shape[0]
    side = math.sqrt(crop_scale)
    offset = rng.uniform(0.0, 1.0 - side, size=(b, 2))  # top-left corner (y, x) in units of the side
    theta = torch.zeros(b, 2, 3, dtype=x.dtype, device=x.device)
    theta[:, 0, 0] = side
    theta[:, 1, 1] = side
    theta[:, 0, 2] = torch.from_numpy(2 * offset[:, 1] + side - 1).to(x)
    theta[:, 1, 2] = torch.from_numpy(2 * offset[:, 0] + side - 1).to(x)
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)


def color_jitter(x: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """Brightness, contrast and saturation jitter of (B, 3, S, S) images in [0, 1], clipped to [0, 1]."""
    b = x.shape[0]
    draws = torch.from_numpy(
        np.stack([rng.uniform(-0.2, 0.2, b), rng.uniform(0.8, 1.2, b), rng.uniform(0.8, 1.2, b)], axis=1)
    ).to(x)
    brightness, contrast, saturation = (draws[:, i].view(b, 1, 1, 1) for i in range(3))
    x = (x + brightness).clamp(0, 1)
    mean = x.mean(dim=(2, 3), keepdim=True)
    x = ((x - mean) * contrast + mean).clamp(0, 1)
    grey = (x * torch.tensor(LUMA, dtype=x.dtype, device=x.device).view(1, 3, 1, 1)).sum(1, keepdim=True)
    return ((x - grey) * saturation + grey).clamp(0, 1)


def augment(x: torch.Tensor, rng: np.random.Generator, crop_scale: float) -> torch.Tensor:
    """Crop then colour jitter, as OpenVLA orders them."""
    return color_jitter(random_crop(x, rng, crop_scale), rng)
