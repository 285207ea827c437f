"""The building blocks every configuration model shares (lidard.config).

``_Model`` forbids unknown keys (a typo in a TOML file is an error naming the key, not a silent
default) and freezes the object (a loaded configuration is a value, shared between the API, the job
queue and the instrument without copies). The annotated float types carry the unit checks.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
