"""The shared JSON encoder: numpy/torch values and non-finite floats."""

import json

import numpy as np
import torch

from neural_bake.io.jsonio import dumps, finite
from neural_bake.types import Frame


def test_dumps_encodes_arrays_tensors_scalars_and_to_dict_objects():
    text = dumps({"a": np.arange(3), "t": torch.tensor([1.5]), "s": np.float32(2.0), "f": Frame((1, 2, 3), 0.5)})
    assert text.endswith("\n")
    assert json.loads(text) == {"a": [0, 1, 2], "t": [1.5], "s": 2.0, "f": {"center": [1, 2, 3], "scale": 0.5}}


def test_non_finite_floats_become_null():
    assert finite({"x": [float("nan"), float("inf"), 1.0], "y": (float("-inf"),)}) == {"x": [None, None, 1.0], "y": [None]}
    assert json.loads(dumps({"psnr": float("inf")})) == {"psnr": None}
