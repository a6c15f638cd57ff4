"""Tie points from the images themselves, guided by the sensor models (``pba match``).

Modules, in the order of the steps: :mod:`raster` (windowed reads through GDAL),
:mod:`orientation` (each image's model, the prediction of one image's pixels in another),
:mod:`features` (SIFT matches inside the predicted band), :mod:`tracks` (multi-image points,
thinning), :mod:`refine` (correlation, epipolar check), :mod:`pipeline` (the steps and the
summary), :mod:`cli` (the command). docs/matching.md is the user's page.
"""
