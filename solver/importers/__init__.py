"""Start from the files a photogrammetrist already has.

One module per format, each describing the format and its conventions in its docstring, with
a reader (located errors: :mod:`~solver.importers.errors`) and, where the format has room, a
writer: survey points (:mod:`~solver.importers.points_csv`), image measurements
(:mod:`~solver.importers.measurements_csv`, :mod:`~solver.importers.qgis_points`,
:mod:`~solver.importers.asp_gcp`), ephemeris and header states
(:mod:`~solver.importers.ephemeris_csv`), attitude (:mod:`~solver.importers.attitude_csv`).
The sensor presets (:mod:`~solver.importers.presets`), the composer of a job document from
all of these (:mod:`~solver.importers.compose`, :mod:`~solver.importers.export` for the way
back) and the ``pba job`` command (:mod:`~solver.importers.job_cli`).
"""
