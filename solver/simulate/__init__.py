"""Scene simulator: independent physics that generates pushbroom jobs with known truth.

Nothing here imports the solver's platform models (``solver.platforms``): the simulator is the
evidence against which those models are judged. It shares only the job schema
(:mod:`solver.schema.job`) and the CRS plumbing (:mod:`solver.geometry.geodesy`).

Layers, each in its own module:

- :mod:`.orbit`      numerical orbit in WGS 84 ECEF (point mass, zonal J2-J4, Earth rotation)
- :mod:`.attitude`   orbit frame, yaw steering, drift, jitter and camera mounting pitch
- :mod:`.camera`     linear-array cameras (focal plane, CCD chips, timing); PRISM and CBERS presets
- :mod:`.iop`        interior-orientation errors of a simulated camera (docs/models.md section 8)
- :mod:`.projection` exact ground -> image (root finding on the line) and image -> ground
- :mod:`.terrain`    a smooth synthetic terrain around the scene
- :mod:`.scene`      point selection, noise, the job document and the truth file
- :mod:`.rpc`        RPC images: the RPC00B fitted to the true geometry plus a known bias
- :mod:`.presets`    ``prism-triplet``, ``prism-single``, ``cbers-scene``, ``strip``
- :mod:`.cli`        ``pba simulate PRESET ...``

Units: metres, seconds, radians unless a name says ``_mm``, ``_px``, ``_deg``. Time ``t_s``
inside the simulator is seconds from the orbit epoch (the instant the satellite is over the
scene centre); the job document's times are ``epoch_s + t_s`` (seconds of the UTC day).
"""
