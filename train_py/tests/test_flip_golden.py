"""The FLIP golden generator is deterministic and reproduces the committed fixture."""

import numpy as np
import pytest
from safetensors.numpy import load_file

from train_py import flip_golden

from .conftest import FIXTURES

#: flip-evaluator is deterministic on the CPU; this only allows for a different build's rounding.
MAP_ATOL = 1e-6


def test_image_pairs_are_deterministic_and_committed():
    a, b = flip_golden.image_pairs(), flip_golden.image_pairs()
    assert a.keys() == b.keys() == flip_golden.REFERENCE.keys()
    for k in a:
        np.testing.assert_array_equal(a[k][0], b[k][0])
        np.testing.assert_array_equal(a[k][1], b[k][1])
    fixture = load_file(str(FIXTURES / "flip_golden.safetensors"))
    ref, test = a["gradient_noise"]
    np.testing.assert_array_equal(fixture["gradient"], ref)
    np.testing.assert_array_equal(fixture["gradient_noise_test"], test)


def test_flip_map_of_one_pair_reproduces_the_fixture():
    flip = pytest.importorskip("flip_evaluator")
    ref, test = flip_golden.image_pairs()["gradient_noise"]
    maps = []
    for _ in range(2):
        err, mean, _ = flip.evaluate(
            ref, test, "LDR", inputsRGB=False, applyMagma=False, parameters={"ppd": flip_golden.PPD}
        )
        maps.append((np.asarray(err, dtype=np.float32).reshape(ref.shape[:2]), np.float32(mean)))
    np.testing.assert_array_equal(maps[0][0], maps[1][0])
    fixture = load_file(str(FIXTURES / "flip_golden.safetensors"))
    np.testing.assert_allclose(maps[0][0], fixture["gradient_noise_map"], rtol=0, atol=MAP_ATOL)
    np.testing.assert_allclose(maps[0][1], fixture["gradient_noise_mean"][0], rtol=0, atol=MAP_ATOL)
