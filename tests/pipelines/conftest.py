"""Shared set-up of the pipeline tests: stage options small enough for a test."""

import pytest

#: Stage options small enough for a test: seconds per asset (process start and imports dominate).
TINY = {
    "sdf": {"width": 16, "depth": 1, "steps": 10, "minutes": None, "pool_surface": 4000, "pool_near": 4000,
            "pool_uniform": 1000, "batch": 512, "batch_near": 512, "batch_uniform": 128, "polish_evals": 0,
            "compile": "off", "gemm_dtype": "float32", "micro_batches": 1,
            "construction": "plain"},  # ten steps of a construction's two levels make no surface to nest
    "nested": {"levels": "8x0", "steps": 20, "certify": False},
    "texture": {"width": 16, "depth": 1, "steps": 20, "minutes": None, "pool": 4000, "batch": 512},
    "coarse": {"spec": "decimate:200"},
    "bake": {"size": 32, "baseline": False, "force": True},  # tiny fits fail the SDF-describes-mesh check
}


def _tiny(**stage_overrides) -> dict:
    out = {s: dict(o) for s, o in TINY.items()}
    for stage, opts in stage_overrides.items():
        out.setdefault(stage, {}).update(opts)
    return out


@pytest.fixture
def tiny():
    """``tiny(stage={field: value}, …)``: the tiny stage options with overrides."""
    return _tiny


@pytest.fixture
def cli_tiny():
    """The tiny stage options as ``--set=STAGE.FIELD=VALUE`` arguments."""
    return [f"--set={stage}.{k}={'none' if v is None else v}" for stage, opts in TINY.items() for k, v in opts.items()]
