"""Parameters of the Li-Wang adaptive-velocity model (DESIGN.md section 3.2; papers/002). Taichi-free."""

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from tflock.config import Float, Int, _rule_error, register_model


def agreement_tolerance(itemsize: int) -> float:
    """Tolerance of eq. (6) for alpha = "inf" at a float size in bytes: agent i moves (at v0) when
    phi_i >= 1 - tol and stays still otherwise.

    1e-6 at f64; 1e-5 at f32, where rounding in a sum over ~100 neighbours can put a fully agreed phi a few 1e-6
    below 1.
    """
    return 1e-6 if itemsize == 8 else 1e-5


def _alpha(value: Any) -> Any:
    """A number >= 0, or infinity (eq. 6) written ``"inf"`` or as TOML's bare ``inf``; nan and -inf are errors."""
    if value == "inf" or (isinstance(value, float) and value == math.inf):
        return "inf"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
        raise _rule_error('must be a number >= 0 or "inf"', value)
    return value


class AdaptiveParams(BaseModel):
    """Li & Wang 2007: agents move at v0 phi_i^alpha along the mean direction of their neighbourhood.

    The default is a large open-space swarm at the paper's density N / L^2 = 12 (N = 300, L = 5): N = 1e5 in an
    initial square of side 91.3, R = 2 as in the paper.
    """

    model_config = ConfigDict(extra="forbid")

    n: Int = Field(100_000, gt=0, description="number of agents N, > 0")
    dim: Literal[2, 3] = Field(2, description="space dimension: 2 (eqs. 4-5) or 3 (eqs. 7-9)")
    box: Float = Field(91.3, gt=0, description="side L of the initial square (cube), > 0; a wall only when periodic")
    radius: Float = Field(2.0, gt=0, description="interaction radius R, > 0 (neighbours |X_i - X_j| <= R)")
    speed: Float = Field(0.5, ge=0, description="maximum speed v0, distance per step, >= 0")
    alpha: Annotated[float | Literal["inf"], BeforeValidator(_alpha)] = Field(
        1.0, description='exponent alpha >= 0 of the speed v0 phi_i^alpha (eq. 5), or "inf" (eq. 6)'
    )
    noise: Float = Field(
        0.0, ge=0, le=math.pi,
        description="noise eta in radians, in [0, pi]: 2D turn xi ~ U[-eta, eta] (eq. 12); 3D uniform in the cone "
                    "of half-angle eta",
    )
    boundary: Literal["open", "periodic"] = Field("open", description="open space (the paper's) or periodic box")


register_model("adaptive", AdaptiveParams, "Li-Wang adaptive velocity (2D and 3D): speed v0 phi^alpha",
               "tflock.models.adaptive:Adaptive")
