"""Vendors' sensor metadata: readers (one module per format) and the exact linescan model they
build, independent of the adjustment (numpy only, :mod:`solver.geometry` for the ellipsoid and
the RPC00B polynomials).

- :mod:`solver.sensors.xmlsafe`: XML read without entity expansion or external entities, and
  located errors (file and element);
- :mod:`solver.sensors.linescan`: the exact pushbroom model (line times, Lagrange ephemeris,
  slerp attitude, a look vector per detector, light-travel time and velocity aberration) with
  image-to-ground and ground-to-image;
- :mod:`solver.sensors.detectors`: the look-angle detector model of SPOT 1-7 and Pleiades
  (tables or polynomials of the look angles' tangents) and the formats' frames;
- :mod:`solver.sensors.maxar`: Maxar/DigitalGlobe support-data XML;
- :mod:`solver.sensors.dimap_spot5`: DIMAP v1 of SPOT 1-5;
- :mod:`solver.sensors.dimap_v2`: DIMAP v2 of SPOT 6/7, Pleiades 1A/1B and Pleiades Neo;
- :mod:`solver.sensors.formats`: which reader a file needs (by its root element);
- :mod:`solver.sensors.agreement`: the exact model against the vendor's RPC, stereo closure;
- :mod:`solver.sensors.job_fragment`: a product as cameras, images and options of our job, and
  how far that form is from the exact model.

Documentation: docs/sensor-metadata.md.
"""
