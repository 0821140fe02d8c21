"""Benchmarks behind `neural-bake bench …`: each prints accuracy against time beside its baseline."""
