"""Applications: the command line (:mod:`.cli`), the statistical campaign (:mod:`.campaign`),
the benchmarks (:mod:`.bench`) and the figures (:mod:`.plots`)."""
