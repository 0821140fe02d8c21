"""The flat public API of neural_bake: every exported name resolves to the object of its module."""

import importlib

import neural_bake as nb


def test_every_export_resolves_to_its_module_object():
    for name, module in nb._EXPORTS.items():
        assert getattr(nb, name) is getattr(importlib.import_module(module, "neural_bake"), name), name
    assert set(nb.__all__) == set(nb._EXPORTS) | {"__version__"}


def test_report_types_are_exported():
    from neural_bake.bake.baker import BakeResult, TexelSample

    assert nb.TexelSample is TexelSample and nb.BakeResult is BakeResult
