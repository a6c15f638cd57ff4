"""Platform models: one registry (:mod:`solver.models.base`, which imports no model) and one
module per model family, each registering its models when imported. Importing any part of this
package runs this file first, so every model is registered, always in the order below (the order
of ``pba models`` and of the reports)."""

# registration: each model module calls solver.models.base.register when imported
import solver.models.kepler  # noqa: F401
import solver.models.orbit_attitude  # noqa: F401
import solver.models.orbit_pass  # noqa: F401
import solver.models.polynomial  # noqa: F401
from solver.models.base import (  # noqa: F401
    ANGLES,
    ELEMENTS,
    HELD,
    ParameterSpec,
    PlatformModel,
    all_models,
    coef_index,
    get_model,
    model_names,
    register,
)
