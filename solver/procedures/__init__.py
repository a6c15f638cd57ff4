"""The adjustment's procedures: one adjustment (:mod:`single`) and those that adjust more than
once on top of it (data snooping, parsimony of the platform terms, significance analysis of
the interior orientation); :func:`solver.adjust.adjust_job` picks them from the job's options."""
