"""Platform models: one registry (:mod:`solver.platforms.registry`, which imports no model) and one
module per model family, each registering its models when imported. Importing any part of this
package runs this file first, so every model is registered, always in the order below (the order
of ``pba models`` and of the reports)."""

# registration: each model module calls solver.platforms.registry.register when imported
import solver.platforms.kepler  # noqa: F401
import solver.platforms.orbit_attitude  # noqa: F401
import solver.platforms.orbit_pass  # noqa: F401
import solver.platforms.polynomial  # noqa: F401
import solver.platforms.rpc_bias  # noqa: F401
from solver.platforms.registry import (  # noqa: F401
    ANGLES,
    ELEMENTS,
    HELD,
    ParameterSpec,
    PlatformModel,
    aliases,
    all_models,
    coef_index,
    get_model,
    model_names,
    register,
)
