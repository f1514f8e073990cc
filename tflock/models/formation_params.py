"""Parameters of the virtual-agent parallel formation model (DESIGN.md section 3.4; papers/004). Taichi-free.

Defaults are the paper's setup (section 4, "Initial conditions") with strategy S-2.2 and the weights of its
Figure 4a (alpha_a = 8, alpha_av = 9, alpha_cv = 4; alpha_c is unused by S-2.2).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from tflock.config import Float, Int, _rule_error, register_model

#: stream id of the ramp-duration draws (rnd of eqs. 1-2); failures use Stream.UPDATE and noise Stream.NOISE
RAMP_STREAM = 300
#: force bits
ALIGN, COHESION, VA_ALIGN, VA_COHESION = 1, 2, 4, 8
#: Table 1: the forces (bit sets) used outside and inside the VAIR, by the strategy's last digit
TABLE_1 = {
    1: (ALIGN | VA_COHESION, VA_ALIGN),
    2: (VA_COHESION, VA_ALIGN | ALIGN),
    3: (VA_COHESION | COHESION, VA_ALIGN | ALIGN),
    4: (VA_COHESION | COHESION | VA_ALIGN | ALIGN, VA_ALIGN | ALIGN),
}
#: what drives an agent at a step (its colour in recordings)
SEPARATION, INSIDE, OUTSIDE, FAILED = 0, 1, 2, 3
STRATEGIES = ("S-1.1", "S-1.2", "S-1.3", "S-1.4", "S-2.1", "S-2.2", "S-2.3", "S-2.4")


class FormationWeights(BaseModel):
    """Control coefficients of eq. (3): the weight of each unit force in the weighted mean."""

    model_config = ConfigDict(extra="forbid")

    align: Float = Field(8.0, ge=0, description="alpha_a, weight of Fa (align with neighbours), >= 0")
    cohesion: Float = Field(1.0, ge=0, description="alpha_c, weight of Fc (toward neighbours' centre of mass), >= 0")
    va_align: Float = Field(9.0, ge=0, description="alpha_av, weight of Fav (align with the virtual agent), >= 0")
    va_cohesion: Float = Field(4.0, ge=0, description="alpha_cv, weight of Fcv (toward the virtual agent), >= 0")


class FormationParams(BaseModel):
    """Reactive agents steered into a parallel formation behind a virtual agent (VA) on a square torus."""

    model_config = ConfigDict(extra="forbid")

    n: Int = Field(12, gt=0, description="number of agents N, > 0")
    strategy: Literal["S-1.1", "S-1.2", "S-1.3", "S-1.4", "S-2.1", "S-2.2", "S-2.3", "S-2.4"] = Field(
        "S-2.2",
        description="Table 1 strategy: S-1.k (one vision radius) or S-2.k (zones: separation, alignment, cohesion "
                    "rings), k = 1..4 picks the forces used outside / inside the VAIR",
    )
    weights: FormationWeights = Field(default_factory=FormationWeights, description="weights of eq. (3)")
    radius: Float = Field(5.5, gt=0, description="vision radius, > 0 (S-2: outer radius of the cohesion zone)")
    align_radius: Float = Field(
        4.0, gt=0, description="S-2 only: outer radius of the alignment zone, in [min_separation, radius]; "
                               "alignment ring [min_separation, align_radius), cohesion ring [align_radius, radius]",
    )
    min_separation: Float = Field(
        2.5, gt=0, description="minimum separation, in (0, radius]: a neighbour closer than this triggers Fs alone "
                               "(eq. 4)",
    )
    max_turn_deg: Float = Field(1.0, gt=0, le=180, description="largest turn each of Fa, Fc, Fav, Fcv asks, degrees")
    separation_turn_deg: Float = Field(2.0, gt=0, le=180, description="largest turn Fs asks, degrees")
    vair: Float = Field(25.0, gt=0, description="VA interaction radius (VAIR), > 0")
    va_speed: Float = Field(1.0, gt=0, description="|va|: speed of the VA and of agents settled inside the VAIR")
    out_speed: Float = Field(1.4, gt=0, description="|vout|: speed of agents settled outside the VAIR, >= va_speed")
    va_heading_deg: Float = Field(180.0, description="fixed heading of the VA, degrees")
    ramp_jitter: Float = Field(
        1.0, ge=0, le=1,
        description="gamma / T of the speed ramps, in [0, 1]: a ramp lasts dt_i = max(1, T + rnd), "
                    "rnd ~ U(-gamma, gamma), T = 2 vair / (out_speed - va_speed) (eqs. 1-2; the paper uses gamma ~ T)",
    )
    fail_prob: Float = Field(
        0.0, ge=0, le=1, description="communication failure p in [0, 1]: an agent ignores all stimuli for one step",
    )
    noise_deg: Float = Field(
        0.0, ge=0, le=180, description="heading noise delta, degrees: eps ~ U[-delta, delta] (eq. 7)",
    )
    beta_lim_deg: Float = Field(5.0, gt=0, le=180, description="tolerance beta_lim of Definition 1, degrees")
    tau_cap: Int = Field(3000, gt=0, description="cap of the quantifier tau, time units")
    world: Float = Field(
        200.0, gt=0,
        description="side of the square torus; must exceed 2 max(vair, reach of the initial rectangle from the VA)",
    )
    init_length: Float = Field(76.0, gt=0, description="initial rectangle's side along the VA heading, behind the VA")
    init_width: Float = Field(36.0, gt=0, description="initial rectangle's side across the VA heading")


    @property
    def ramp_time(self) -> float:
        """T of the speed ramps (eqs. 1-2): "the approximate time for the agent to move from the VAIR boundary to
        the VA's position" while it slows down. An agent chasing the VA enters at |vout| and closes on it at
        |vout| - |va|; eq. (1) brings that closing speed linearly to 0 over the ramp, so a ramp of length dt gains
        (|vout| - |va|) dt / 2 on the VA, and the VA is reached when that equals the VAIR:
        T = 2 vair / (|vout| - |va|) (125 tu at the paper's 25 bl, 1.4 and 1 bl/tu). With the jitter gamma = T a
        ramp's length is uniform in (0, 2T) and the depth gained uniform in (0, 2 vair): an agent entering from
        straight behind comes to rest anywhere on the VAIR's diameter, behind or in front of the VA, the paper's
        "homogeneous distribution of agents inside the VAIR". (In whole steps the gain is
        (|vout| - |va|)(K - K (K + 1) / (2 dt)), K = floor(dt): half a step's worth less.) Equal speeds make the
        ramps flat and T moot (2 vair / |va| then)."""
        closing = self.out_speed - self.va_speed
        return 2 * self.vair / (closing if closing > 0 else self.va_speed)

    @model_validator(mode="after")
    def _cross_field_rules(self) -> FormationParams:
        if self.min_separation > self.radius:
            raise _rule_error(f"must be <= params.radius (= {self.radius:g})", self.min_separation,
                              key="min_separation")
        if not self.min_separation <= self.align_radius <= self.radius:
            raise _rule_error(
                f"must be in [params.min_separation, params.radius] (= [{self.min_separation:g}, {self.radius:g}])",
                self.align_radius, key="align_radius")
        if self.out_speed < self.va_speed:
            raise _rule_error(f"must be >= params.va_speed (= {self.va_speed:g})", self.out_speed, key="out_speed")
        reach = math.hypot(self.init_length, self.init_width / 2)
        need = 2 * max(self.vair, reach, self.radius, self.out_speed)
        if self.world <= need:
            raise _rule_error(
                f"must be > {need:g} (twice the largest of vair, the initial rectangle's reach from the VA, radius)",
                self.world, key="world")
        return self


register_model("formation", FormationParams,
               "Virtual-agent parallel formations (Table 1 strategies S-1.1..S-2.4, VAIR, speed ramps)",
               "tflock.models.formation:Formation")
