"""Fitting: sampling, SDF fitting, nested sequences (δ), texture fitting."""
