"""SDF and colour fields: analytic oracles, GEMM normals against autograd, zero gradients, model files."""

import pytest
import torch

from neural_bake.fields import ColorField, SdfField, TextureField, load_field, load_sdf_field, save_model
from neural_bake.errors import ModelFileError
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame


def test_sphere_field_values_and_normals(rng):
    p = torch.as_tensor(rng.normal(size=(200, 3)))
    f = SdfField(lambda x: x.norm(dim=1) - 0.5)
    v, n, ok = f.value_and_normal(p)
    assert v.dtype == torch.float64 and n.shape == (200, 3) and ok.all()
    torch.testing.assert_close(v, p.norm(dim=1) - 0.5)
    torch.testing.assert_close(n, p / p.norm(dim=1, keepdim=True))


def test_explicit_gradient_is_used():
    p = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64)
    f = SdfField(lambda x: x[:, 0] * 0, gradient=lambda x: torch.tensor([[0.0, 0.0, -4.0]], dtype=x.dtype))
    _, n, ok = f.value_and_normal(p)
    assert ok.item() and torch.equal(n, torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_siren_field_matches_autograd(dtype):
    torch.manual_seed(0)
    model = Siren(32, 1, generator=torch.Generator().manual_seed(1)).to(dtype)
    p = (torch.rand(300, 3, dtype=dtype) * 2 - 1)
    v, n, ok = SdfField.from_model(model).value_and_normal(p)
    q = p.clone().requires_grad_(True)
    out = model(q).reshape(-1)
    (g,) = torch.autograd.grad(out.sum(), q)
    ref = g / g.norm(dim=1, keepdim=True)
    tol = 1e-4 if dtype == torch.float32 else 1e-10
    assert v.dtype == dtype and ok.all()
    torch.testing.assert_close(v, out.detach(), atol=tol, rtol=tol)
    torch.testing.assert_close(n, ref, atol=tol, rtol=tol)


def test_zero_gradient_gives_finite_invalid_normals():
    p = torch.zeros(5, 3, dtype=torch.float64)
    f = SdfField(lambda x: (x**2).sum(dim=1) - 1.0)  # ∇f = 2x = 0 at the origin
    v, n, ok = f.value_and_normal(p)
    assert not ok.any()
    assert torch.isfinite(n).all() and torch.equal(n, torch.zeros_like(n))
    assert torch.equal(v, -torch.ones(5, dtype=torch.float64))


def test_nan_values_become_invalid_not_nan():
    f = SdfField(lambda x: x[:, 0] * float("nan"))
    v, n, ok = f.value_and_normal(torch.ones(3, 3, dtype=torch.float64))
    assert not ok.any() and torch.isfinite(n).all() and torch.isinf(v).all()


def test_color_field_from_model_and_analytic():
    model = Siren(16, 0, out_dim=3, generator=torch.Generator().manual_seed(2))
    p = torch.rand(10, 3)
    c = ColorField.from_model(model).color(p)
    torch.testing.assert_close(c, model(p).detach())
    c2 = ColorField(lambda x: torch.full((x.shape[0], 3), float("nan"))).color(p)
    assert torch.equal(c2, torch.zeros(10, 3))


def test_wrong_output_counts_raise():
    with pytest.raises(ModelFileError, match="SDF model must have 1 output"):
        SdfField.from_model(Siren(8, 0, out_dim=3))
    with pytest.raises(ModelFileError, match="texture model must have 3 or 4 outputs"):
        ColorField.from_model(Siren(8, 0, out_dim=1))


def test_load_field_kinds_and_errors(tmp_path):
    frame = Frame((1.0, 2.0, 3.0), 0.5)
    sdf_path = save_model(Siren(8, 0), tmp_path / "a.sdf", kind="sdf", frame=frame.to_dict(), delta=0.02)
    tex_path = save_model(Siren(8, 0, out_dim=3), tmp_path / "a.tex", kind="texture", frame=frame.to_dict())
    f = load_field(sdf_path)
    assert isinstance(f, SdfField) and f.delta == 0.02 and f.frame == frame and f.name == "a.sdf"
    assert f.metadata["kind"] == "sdf" and f.in_dim == 3
    g = load_field(tex_path)
    assert isinstance(g, TextureField) and g.frame == frame and g.delta is None
    with pytest.raises(ModelFileError, match=r"a\.tex: a TextureField file, expected an SDF model file"):
        load_sdf_field(tex_path)
    with pytest.raises(ModelFileError, match=r"missing\.sdf: no such model file"):
        load_field(tmp_path / "missing.sdf")


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_closest_surface_points_of_a_sphere(dtype):
    from neural_bake.fields import closest_surface_points

    p = torch.tensor([[0.0, 0.0, 1.3], [0.8, 0.0, 0.0], [0.0, 2.0, 0.0]], dtype=dtype)
    r = p.norm(dim=1)
    values, normals = r - 1.0, p / r[:, None]
    valid = torch.tensor([True, True, False])
    q = closest_surface_points(p, values, normals, valid)
    assert q.dtype == dtype
    torch.testing.assert_close(q[:2].norm(dim=1), torch.ones(2, dtype=dtype))  # onto the unit sphere
    torch.testing.assert_close(q[2], p[2])  # no gradient: stays
    q = closest_surface_points(p, values, normals, valid, reach=0.1)  # moved by 0.1 at most
    torch.testing.assert_close(q[:2].norm(dim=1), torch.tensor([1.2, 0.9], dtype=dtype))
