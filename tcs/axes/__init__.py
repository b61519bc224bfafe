"""The OpenTCI generic axis: motion core (pure, plain data in and out).

* :mod:`tcs.axes.profile` — :class:`Setpoint`, :class:`AxisDynamics`, the ruckig adapter,
  :func:`theoretical_minimum_time`.
* :mod:`tcs.axes.limits` — :class:`SoftLimits` (RANGE, cyclic axes, cable wrap) and
  :class:`LimitGuard` (every setpoint checked).
* :mod:`tcs.axes.motion` — :class:`MotionPlanner`: jerk-limited point-to-point motion
  (``TARGETPOS``, ``OFFSET``, ``CURRSPEED``, ``STOP``).
* :mod:`tcs.axes.trajectory` — :class:`TrajectoryQueue`: the ``TRAJECTORY`` points and their
  C2 interpolation.
* :mod:`tcs.axes.follower` — :class:`TrajectoryFollower`: intercept, follow, events.
"""

from tcs.axes.follower import FollowerState, FollowStep, TrajectoryFollower
from tcs.axes.limits import LimitGuard, SoftLimits
from tcs.axes.motion import MotionPlanner, PlannerState
from tcs.axes.profile import AxisDynamics, Setpoint, theoretical_minimum_time
from tcs.axes.trajectory import AddResult, TrajectoryBufferFull, TrajectoryQueue

__all__ = [
    "AddResult", "AxisDynamics", "FollowStep", "FollowerState", "LimitGuard", "MotionPlanner",
    "PlannerState", "Setpoint", "SoftLimits", "TrajectoryBufferFull", "TrajectoryFollower",
    "TrajectoryQueue", "theoretical_minimum_time",
]
