"""What an estimator can weigh on without while the health monitor names a signal: the
degraded-weighing hooks :class:`~.base.Estimator` inherits (:class:`DegradedWeighing`).

Each hook says per instance which named signals it weighs on without (a rate replaced by the
angle's slope, a pressure's joint dropped, an angle integrated from its rate, a tilt held);
:meth:`~.base.Estimator.step_values` asks them (docs/sensor-health.md, "Degraded weighing").
"""

from __future__ import annotations

from typing import ClassVar


class DegradedWeighing:
    """The degraded-weighing hooks and their class-level defaults (none: a named signal stops
    the weighing, ``sensor_fault``)."""

    #: The link rates it weighs on without while the health monitor names them (stuck, dropout,
    #: noise): replaced by the angle's slope, status ``degraded`` (:meth:`.health.HealthMonitor
    #: .substitute`; :meth:`degraded_rates` per instance). None by default: an estimator opts in
    #: where its error on the substitute was measured within its widened sigma
    #: (docs/sensor-health.md); the others stop (``sensor_fault``) as before.
    DEGRADED_RATES: ClassVar[tuple[str, ...]] = ()
    #: The cylinder pressures whose joint it weighs on without while the monitor names them
    #: (stuck, dropout, noise): the joint dropped from the weighing, status ``degraded``
    #: (:meth:`degraded_pressures` per instance, :meth:`_drop_joints`). None by default.
    DEGRADED_PRESSURES: ClassVar[tuple[str, ...]] = ()
    #: The link angles it weighs on with the rate integrated from the last healthy angle while
    #: the monitor names them (stuck, dropout), for a bounded time (:meth:`degraded_angles`).
    DEGRADED_ANGLES: ClassVar[tuple[str, ...]] = ()
    #: The house tilts it weighs on with their value from before the fault while the monitor
    #: names them, for a bounded time (:meth:`degraded_tilts`).
    DEGRADED_TILTS: ClassVar[tuple[str, ...]] = ()

    def degraded_rates(self) -> tuple[str, ...]:
        """The link rates this estimator weighs on without (:attr:`DEGRADED_RATES`; an estimator
        whose options change what it can weigh without overrides it).

        Returns
        -------
        tuple of str
            Signal names (empty: no degraded weighing).
        """
        return self.DEGRADED_RATES

    def degraded_pressures(self) -> tuple[str, ...]:
        """The cylinder pressures whose joint this estimator weighs on without
        (:attr:`DEGRADED_PRESSURES`; an estimator whose options change it overrides it).

        Returns
        -------
        tuple of str
            Signal names (empty: a named pressure stops the weighing).
        """
        return self.DEGRADED_PRESSURES

    def degraded_angles(self) -> tuple[str, ...]:
        """The link angles this estimator weighs on with the integrated rate
        (:attr:`DEGRADED_ANGLES`; an estimator whose options change it overrides it).

        Returns
        -------
        tuple of str
            Signal names (empty: a named angle stops the weighing).
        """
        return self.DEGRADED_ANGLES

    def degraded_tilts(self) -> tuple[str, ...]:
        """The house tilts it weighs on with their value from before the fault
        (:attr:`DEGRADED_TILTS`; empty: a named tilt stops the weighing)."""
        return self.DEGRADED_TILTS

    def _drop_joints(self, joints: tuple[bool, ...]) -> None:
        """Weigh the next sample without these link joints (boom, dipper, bucket; all False:
        every joint), for an estimator with :meth:`degraded_pressures`.

        Parameters
        ----------
        joints : tuple of bool
            Per joint, whether it is dropped.
        """

    def _forget_joints(self, joints: tuple[bool, ...]) -> None:
        """Weigh none of these link joints' windows over the samples held now (a signal just
        named: its samples before the name; an estimator with :meth:`degraded_pressures`)."""

    def jump_limit(self) -> float | None:
        """The largest move of an ``ok`` estimate from the one before while the monitor runs, kg
        (beyond it ``load_changing``: :data:`.health.JUMP_SHARE`); None (default): no such rule.

        Returns
        -------
        float or None
            The limit, kg, or None.
        """
        return None
