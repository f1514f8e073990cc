"""Parameters of the Tanner-Jadbabaie-Pappas potential-field flocking model (DESIGN.md 3.3; papers/001)."""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictStr, model_validator

from tflock.config import Float, Int, _rule_error, register_model
from tflock.models.potential_graphs import DENSE_GRAPH_MAX, GraphError, check_connected, read_edge_file

#: largest packing fraction of the discs (balls) of diameter min_separation the initial draw accepts
MAX_PACKING = {2: 0.3, 3: 0.2}


class PotentialParams(BaseModel):
    """Double integrators with velocity alignment and the artificial potential V(r) = d^2 / r^2 + ln(r^2)."""

    model_config = ConfigDict(extra="forbid")

    n: Int = Field(100_000, gt=0, description="number of agents N, > 0")
    dim: Literal[2, 3] = Field(2, description="space dimension, 2 or 3")
    box: Float = Field(
        500.0,
        gt=0,
        description="side of the initial square (cube) of positions, centred at the origin, > 0 "
        "(open space; the paper's (-2.5, 2.5)^2 is box = 5)",
    )
    radius: Float = Field(
        2.0, gt=0, description="switching topology: interaction radius R > desired_distance (neighbours: |r_ij| < R)"
    )
    desired_distance: Float = Field(1.0, gt=0, description="desired distance d, the minimum of V, 0 < d < R")
    speed: Float = Field(1.0, gt=0, description="initial speeds are uniform in (0, speed), random directions, > 0")
    dt: Float = Field(0.01, gt=0, description="time step of the semi-implicit (symplectic) Euler integrator, > 0")
    topology: Literal["switching", "fixed"] = Field(
        "switching", description="switching (neighbours within R, section 5) or fixed (a connected graph, section 4)"
    )
    graph: Literal["random", "complete", "path", "ring", "tree", "file"] = Field(
        "random",
        description="fixed topology: the graph family: random (connected G(n, p)), complete, path, ring, "
        "tree (random recursive) or file",
    )
    graph_p: Float = Field(0.3, gt=0, le=1, description="fixed random graph: edge probability, in (0, 1]")
    graph_file: StrictStr = Field(
        "", description="fixed topology with graph = file: edge list, one 'i j' pair of 0-based ids a line"
    )
    min_separation: Float = Field(
        0.25, ge=0, description="minimum initial distance between agents, >= 0 and < desired_distance"
    )
    lambda2_every: Int = Field(
        10, ge=1, description="algebraic connectivity lambda_2 (small n only) is recomputed every k steps, k >= 1"
    )

    @model_validator(mode="after")
    def _cross_field_rules(self) -> PotentialParams:
        if self.desired_distance >= self.radius:
            raise _rule_error(f"must be < params.radius (= {self.radius:g}), the potential's minimum lies inside R",
                              self.desired_distance, key="desired_distance")
        if self.min_separation >= self.desired_distance:
            raise _rule_error(f"must be < params.desired_distance (= {self.desired_distance:g})",
                              self.min_separation, key="min_separation")
        ball = math.pi / 4 if self.dim == 2 else math.pi / 6  # volume of a ball of unit diameter
        # a product of the ratio (it overflows to inf; a power of a huge float raises)
        packing = self.n * ball * math.prod([self.min_separation / self.box] * self.dim)
        if packing > MAX_PACKING[self.dim]:
            raise _rule_error(f"too large for n = {self.n} in a box of side {self.box:g} (packing fraction "
                              f"{packing:.2f} > {MAX_PACKING[self.dim]})", self.min_separation, key="min_separation")
        if self.topology == "fixed":
            if self.graph in ("complete", "random") and self.n > DENSE_GRAPH_MAX:
                raise _rule_error(f"'{self.graph}' is limited to n <= {DENSE_GRAPH_MAX} (use tree, path, ring or "
                                  f"file for larger n; n = {self.n})", self.graph, key="graph")
            if self.graph == "file":
                if not self.graph_file:
                    raise _rule_error("must name an edge-list file for graph = 'file'", self.graph_file,
                                      key="graph_file")
                try:
                    check_connected(self.n, read_edge_file(self.graph_file, self.n), f"the graph in {self.graph_file}")
                except GraphError as error:
                    raise _rule_error(str(error), self.graph_file,
                                      key="graph_file") from None
        return self


register_model("potential", PotentialParams, "Tanner-Jadbabaie-Pappas potential-field flocking, double integrator",
               "tflock.models.potential:Potential")
