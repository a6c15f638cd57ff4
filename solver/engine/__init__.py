"""The adjustment's stages: validate, assemble, initialize, tables, the Ceres backend, linearisation and covariance."""
