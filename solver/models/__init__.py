"""Platform models: one registry (see :mod:`solver.models.base`)."""

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
