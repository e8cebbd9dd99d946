"""The SGBM sources' texture confidence (device.sources.sgbm.texture_confidence): the signal's share of
the horizontal gradient energy, against images whose texture and noise are known."""

from __future__ import annotations

import numpy as np
import pytest

from device.sources.sgbm import NOISE_FLOOR_GREY, SGBMConfig, compute_disparity, image_noise_sigma, texture_confidence


def _image(noise: float, seed: int = 0) -> np.ndarray:
    """240 x 320 grey: a plain left half (128 + noise) and a right half of random texture (std 40) + noise."""
    rng = np.random.default_rng(seed)
    img = np.full((240, 320), 128.0)
    img[:, 160:] += rng.normal(0.0, 40.0, (240, 160))
    img += rng.normal(0.0, noise, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("noise", [2.0, 4.0, 8.0])
def test_noise_is_read_from_the_flat_part(noise):
    sigma = image_noise_sigma(_image(noise).astype(np.float32))
    assert abs(sigma - noise) / noise < 0.25, sigma


def test_noise_never_below_the_floor():
    assert image_noise_sigma(np.full((50, 60), 77, np.float32)) == NOISE_FLOOR_GREY


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plain_is_unsupported_and_texture_supported(seed):
    c = texture_confidence(_image(3.0, seed))
    assert c.shape == (240, 320) and c.dtype == np.float32
    assert np.median(c[:, 20:140]) < 0.2
    assert np.median(c[:, 180:300]) > 0.9


def test_rows_of_stripes_carry_no_horizontal_texture():
    # Texture only along y (horizontal stripes) tells no horizontal disparity apart.
    rng = np.random.default_rng(5)
    img = np.repeat(rng.integers(0, 255, (240, 1)), 320, axis=1) + rng.normal(0, 2.0, (240, 320))
    c = texture_confidence(np.clip(img, 0, 255).astype(np.uint8))
    assert np.median(c) < 0.3  # below 0.5 (signal energy equal to the noise energy) nearly everywhere
    assert np.mean(c < 0.5) > 0.9


def test_confidence_is_zero_where_sgbm_did_not_match():
    left = np.dstack([_image(2.0)] * 3)
    right = np.roll(left, -8, axis=1)
    disp, conf = compute_disparity(left, right, SGBMConfig(num_disparities=32))
    assert (conf[~np.isfinite(disp)] == 0).all() and conf.max() <= 1.0
    textured = np.isfinite(disp[:, 200:300])
    assert np.median(conf[:, 200:300][textured]) > 0.9
