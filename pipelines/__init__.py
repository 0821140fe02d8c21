"""Asset and batch pipelines (installed as ``neural_bake.pipelines``): chains of library calls only."""
