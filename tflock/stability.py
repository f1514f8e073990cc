"""The integrator-stability guard: a run that is finite but no longer integrates its model's equations.

A time step too large for an explicit integrator does not always overflow: ``potential`` with ``dt = 1e6`` throws the
agents apart in its first step (speeds ~1e7) and then coasts, finite and meaningless. At the default dt = 0.01 a
dense 3D swarm (n = 2000 in a box of 20, seed 0) meets close encounters near r = 0.1 d, where a pair's stiffness
V''(r) ~ 6 d^2 / r^4 puts dt past the explicit step's limit, and from step ~870 its Q climbs from -1.5e3 to 1.8e6.
Models whose integrator can leave its stable range (only ``potential``: the other models move their agents a fixed
speed per step) give the guard two quantities:

* **Lyapunov test** (:meth:`tflock.models.base.Model.lyapunov`). For papers/001, W = 1/2 sum_i (V_i + |v_i|^2)
  (eq. 5, fixed graph) and Q (eq. 10, switching; here less its constant) obey dW/dt = -v^T (L x I) v <= 0 (eqs. 8
  and 12): they never rise above their value at step 0, W_0. A stable integrator adds an error that is a small
  fraction of the energy the system holds (O(dt) relative to it for the semi-implicit Euler scheme, and the
  alignment term dissipates more); an unstable one makes it grow geometrically. The run stops once

      W(t) > W_0 + SLACK (K_0 + |P_0|),

  K_0 and P_0 the kinetic and potential parts of W_0: W has risen by more than all the energy the system started
  with. It needs the pair energies, which the metrics compute anyway: it runs at every metrics step, every
  checkpoint and the last step, where it costs one sum over the velocities.
* **Displacement test** (:meth:`tflock.models.base.Model.step_spread`): two agents moving apart by more than the
  desired distance d in one step (dt times the largest spread of a velocity component) skip over the potential's
  whole shape, so the step no longer follows eq. (3). It is one pass over the velocities and runs at every step
  the guard checks (frames too).

The potential runs in configs/ and configs/papers/ stay far inside both: W and Q never rise above W_0, and two
agents move at most 0.08 d (configs/potential.toml, its first steps) and 0.015 d (tanner-fixed, tanner-switching)
apart in a step; ``dt = 1e6`` fails both at step 1 (tests/test_stability.py).
"""

from __future__ import annotations

from tflock.models.base import Lyapunov, Model

#: W may exceed its value at step 0 by at most this many times the energy held at step 0 (K_0 + |P_0|)
SLACK = 1.0


def cheap_test(model: Model) -> str | None:
    """The displacement test: why the state is unstable, as a clause of one line, or None."""
    spread = model.step_spread()
    if spread is None or spread[0] <= spread[1]:
        return None
    moved, length = spread
    return (f"the integration is unstable: two agents move {moved:.4g} apart in one step, more than the desired "
            f"distance {length:g} over which the potential changes")


def lyapunov_test(start: Lyapunov | None, model: Model) -> str | None:
    """The Lyapunov test against the value at step 0, `start`: why the state is unstable, or None."""
    now = model.lyapunov()
    if start is None or now is None or now.value <= start.value + SLACK * start.scale:
        return None
    return (f"the integration is unstable: the Lyapunov function {now.name} rose from {start.value:.4g} at step 0 "
            f"to {now.value:.4g}, more than the {start.scale:.3g} of energy the system started with (it must not "
            f"increase: papers/001 eqs. 8 and 12)")
