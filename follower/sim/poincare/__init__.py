"""The simulated walker's own Poincare map (the 3-D counterpart of eqs. 24-26).

The reduced model (20)-(23) is the only walker whose map the paper computes. Here the map
is that of the walker the follower really runs: pybullet physics, the gait
(:mod:`bipedtele.follower.sim.gait`) and the follower's servo (the reference model (28)
with the observer (12), :class:`~bipedtele.control.reference.RealFollowerReference`, at
the follower's control rate), with a constant reference and no network.

Section
    The touchdown of a chosen foot. The gait is clock-driven, so the touchdown is the
    scheduled end of the step whose swing leg is that foot; the section is the control
    tick at that instant, after the tick (observe, servo, send). ``T/2`` must be a
    multiple of both the physics period and the control period, so that every touchdown
    falls on a tick and the map is autonomous (:func:`check_alignment`).
State (:func:`state_names`, 50 values)
    Base height, roll and pitch; base linear and angular velocity in the heading frame;
    the 12 joint angles and rates; the servo's commanded speeds ``eta`` and observer
    estimates ``z_r`` (gait phase variables: what the gait latches at touchdown); the
    gait's reference pose at touchdown (12 angles, the start of the next step's joint
    references) and its lateral sway. Horizontal position and yaw are left out: the map
    is invariant to them on flat ground (they would add the neutral eigenvalue 1).
Map
    From a state at the section, run the walker until the same foot touches down again
    (one walking cycle ``T``, two steps, like the reduced model's one reset per cycle).
Jacobian
    Central differences (26) around the fixed point; every evaluation restores the
    whole simulation (pybullet ``saveState``/``restoreState`` plus the Python state of
    the robot, its gait and the servo) and applies one perturbation.
Fixed point
    Found by walking until steady (``warmup_s``) from standing and averaging the section
    states of ``average_cycles`` cycles; its residual ``|P(x*) - x*|`` (scaled by the
    perturbation sizes) is reported. That average is not a fixed point of the map: with
    ``newton_iterations`` (``--newton N``) damped Newton steps on ``P(x) - x = 0`` refine
    it (:meth:`WalkerMap.newton`), and the radius of (26) is measured there at 0.3, 1 and
    3 times the perturbation sizes.
Limit cycle
    The per-tick speeds over the averaging cycles give an oscillation marker
    (:meth:`WalkerMap.steady`): the turn loop's limit cycle at high turn damping is
    periodic in ``T``, so the section sees a fixed point there.
Table
    ``--table FILE`` tabulates the map over forward damping x turn damping x ``T``
    (:func:`walker_table`): the surrogate of ``control.hybrid_model = "walker"``
    (:mod:`bipedtele.control.walker_map`, docs/walker_map.md).

Perturbation sizes are small and physical (1 mm-scale, 1 mrad-scale, :data:`DELTAS`),
not the paper's ``dq = 1`` (rad), ``dqdot = 0.375``: the reduced model is affine, so any
size is exact there, while a perturbation of 1 rad would topple the 3-D walker.

Modules (one job each)
    :mod:`.state` the state vector, its perturbation sizes, the alignment check and
    :class:`MapSettings`; :mod:`.servo` the walker with its servo and save/restore
    (:class:`WalkerServo`); :mod:`.map` the map at one operating point
    (:class:`WalkerMap`, :func:`walker_rho`); :mod:`.newton` the Newton solve of
    ``P(x) = x``; :mod:`.sweep` the operating point and the grid (:func:`poincare_grid`);
    :mod:`.table` the surrogate table (:func:`walker_table`); :mod:`.plot` the figure;
    :mod:`.cli` ``bipedtele poincare``. Every name is importable from this package.
"""

from bipedtele.control.walker_map import TABLE_FORMAT
from bipedtele.follower.sim.poincare.cli import add_poincare_parser, add_walker_arg, walker_torque
from bipedtele.follower.sim.poincare.map import WalkerMap, WalkerMapResult, walker_rho
from bipedtele.follower.sim.poincare.newton import NewtonResult, solve_fixed_point
from bipedtele.follower.sim.poincare.plot import plot_poincare
from bipedtele.follower.sim.poincare.servo import WalkerServo
from bipedtele.follower.sim.poincare.state import (
    CM,
    DELTAS,
    MapSettings,
    alignment_quantum,
    check_alignment,
    perturbation_sizes,
    state_names,
)
from bipedtele.follower.sim.poincare.sweep import grid, operating_point, poincare_grid
from bipedtele.follower.sim.poincare.table import walker_table

__all__ = [
    "CM",
    "DELTAS",
    "TABLE_FORMAT",
    "MapSettings",
    "NewtonResult",
    "WalkerMap",
    "WalkerMapResult",
    "WalkerServo",
    "add_poincare_parser",
    "add_walker_arg",
    "alignment_quantum",
    "check_alignment",
    "grid",
    "operating_point",
    "perturbation_sizes",
    "plot_poincare",
    "poincare_grid",
    "solve_fixed_point",
    "state_names",
    "walker_rho",
    "walker_table",
    "walker_torque",
]
