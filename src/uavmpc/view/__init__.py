"""What people watch: the 3-D scene of a flight (:mod:`uavmpc.view.scene`), written into logs
and served live to Foxglove (:mod:`uavmpc.view.live`, the ``viz`` extra)."""
