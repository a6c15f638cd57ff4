"""Tolerances whose meaning recurs in several test files, each named once with what it protects:
the error it lets through against the size of the bug it must still catch. A tolerance with a
meaning of its own stays a module-level constant of its test file."""

# The same float64 number computed by another formula or in another order (a sum of a few dozen
# terms, a quotient or a quantile read back from a report, a value written and read again): a
# few ulps. A wrong divisor, degree of freedom, axis or scale is off by 1e-3 or more.
SAME_NUMBER_REL = 1e-12

# A statistic recomputed from the numbers a report lists (sums of hundreds of squares, solves
# with 2 x 2 and 3 x 3 covariances, scipy evaluated twice, the same adjustment run twice):
# rounding grown by the conditioning of the covariances. A wrong formula is off by 1e-6 or more.
RECOMPUTED_REL = 1e-9

# The total redundancy, a sum of a few hundred redundancy numbers each within ~1e-6 of the dense
# hat matrix's, equals the degrees of freedom; a group of observations left out is worth 0.01-2.
REDUNDANCY_SUM_ABS = 1e-3

# Positions computed two ways through the geodesy (ours against pyproj, a round trip, a height
# on a ray): one micrometre; a wrong ellipsoid, datum, axis order or height is metres.
GEODESY_M = 1e-6

# Elements of rotation matrices, and angles (rad), rebuilt another way: rounding of products of
# unit-size terms; a wrong sign, axis or order of rotations is of order one.
ROTATION_ABS = 1e-12

# A pixel taken to the ground and back (a ray or image_to_ground, then the projection): the
# line searches and Newton steps stop below 1e-8 line; a wrong line time, convention or chip is
# half a pixel or more.
ROUND_TRIP_PX = 1e-6

# The same RPC evaluated by GDAL and by us (GDAL's ground-to-image iterates): a convention error
# (pixel corner vs centre, line vs sample) is half a pixel or more.
SAME_RPC_PX = 1e-6

# A ground point through an image or a CRS and back: the intersection's and the CRS's own
# tolerances; a wrong height, datum or axis order is metres.
GROUND_ROUND_TRIP_M = 1e-3

# Shapiro-Wilk's W and p-value, ours (exact normal scores) against scipy.stats.shapiro (AS R94,
# whose normal scores come from a 7-digit approximation): differences of ~1e-7 at most; a wrong
# coefficient or transformation is 1e-3 or more.
SHAPIRO_ABS = 1e-6
