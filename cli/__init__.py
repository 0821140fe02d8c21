"""The `neural-bake` command (installed as ``neural_bake.cli``): one thin module per verb."""
