"""Parameter blocks: one module per kind of block (:mod:`solver.blocks.kind`), listed in
:mod:`solver.blocks.registry` (the images' platform parameters, the cameras' interior
orientation, the passes' orbit states). The observation families' terms act on them."""
