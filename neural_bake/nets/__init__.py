"""Networks: Siren, GEMM normals (closed-form gradients), range analysis, model files."""
