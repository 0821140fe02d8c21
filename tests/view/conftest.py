"""An analytic bake of the bumpy sphere (exact normals and colours baked onto a decimated mesh), shared."""

import pytest

from neural_bake.view.analytic import analytic_bake


@pytest.fixture(scope="session")
def bumpy_bake(tmp_path_factory):
    return analytic_bake(tmp_path_factory.mktemp("bumpy"))


@pytest.fixture(scope="session")
def make_analytic_bake():
    return analytic_bake
