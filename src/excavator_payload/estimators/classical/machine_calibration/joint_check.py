r"""The calibrated kernel's joint consistency check (``--joint-check``): :class:`JointCheck`.

A pressure offset, drift or gain error of one cylinder biases only its own joint's balance (the
boom cylinder's force is internal to the dipper's and bucket's free bodies), so the joints'
estimates part. The kernel (:class:`~.kernel.CalibratedKernel`) sums each joint's share of the
weighing; after every balance window :meth:`JointCheck.update` judges the joints against one
another on its own copy of those sums, which restarts with the weighing (a new load) and after a
pause, so that it compares what the joints weighed under one load:

* a joint is compared only once its own σ, (:data:`~.settings.JOINT_INFO_INFLATION` / I_j)^½,
  is within :data:`~.settings.JOINT_CHECKED_SHARE` of the rated payload (and an ``ok`` estimate
  needs two compared joints);
* **pause**: while the new-load test's short memory has left the whole weighing by
  :data:`~.settings.JOINT_CHANGE_SHARE` of the rated payload (and
  :data:`~.settings.CHANGING_SIGMAS`), a new fault is held and the kernel says
  ``load_changing``: in a dump the joints that move see the load leave first, while a standing
  boom, which carries most of the information, keeps the whole weighing where it was. The pause
  ends when the memories agree again (the check then starts from nothing, and so does the
  weighing, whose sums hold the windows the pause saw: :attr:`restart`) or after
  :data:`~.settings.JOINT_PAUSE_WINDOWS` windows that weigh anything (a lasting difference: a
  held fault is named at once). A fault whose one joint holds more than half of the compared
  information is not held: the whole weighing follows that joint, the change is its doing;
* **dump**: while the bucket opens fast (the kernel's ``dumping``,
  :data:`~.settings.DUMP_OPENING_RATE`, held :data:`~.settings.DUMP_HOLD` s) a load can leave,
  so a window then is not summed and a new fault is held whichever joint leads; so too before
  the weighing is ready (a new load's first windows: a fill, a dig);
* **slight**: a new fault of one joint is held while the weighing on the check's sums moves by at
  most :data:`~.settings.JOINT_SLIGHT_SHARE` of the rated payload without that joint: so little
  information is as likely the joint's own model error as a sensor.
* **a load left in a dump**: a joint weighed before the last dump and after it that weighs less
  after it (by :data:`~.settings.JOINT_CHANGE_SHARE` of the rated payload and beyond
  :data:`~.settings.JOINT_CHI2`) restarts the weighing, as a new load: a load too small for the
  new-load test otherwise leaves the joints that stand with the old load's sums (:meth:`_dumped_load`).
* **a bucket that crossed**: a new fault of the bucket (:data:`~.settings.SIDE_JOINTS`) whose
  sums hold windows of both signs of its regressor φ_j (the payload's torque about it passed
  zero: a bucket curled past the pose where the load sits over its pin) is held while the joint weighed on one side alone agrees with the
  others (:meth:`_side_agrees`): a pressure's bias shows on both sides (b / φ_j), the model's
  error where the payload's lever is short on one (the braked end of a curl,
  docs/findings/false-alarms.md).

What was measured with it is in docs/sensor-health.md ("The joint check").
"""

from __future__ import annotations

import math

from excavator_payload.estimators.classical.machine_calibration.settings import (
    CHANGING_SIGMAS, JOINT_CHANGE_SHARE, JOINT_CHECKED_SHARE, JOINT_CHI2, JOINT_INFO_INFLATION,
    JOINT_MODEL_SHARE, JOINT_MOVING_SHARE, JOINT_MOVING_WINDOWS, JOINT_PAUSE_WINDOWS, JOINT_PRESSURES, JOINT_SAMPLES,
    JOINT_SLIGHT_SHARE, LONE_YOUNG_SHARE, PAUSE_RESTARTS, SIDE_JOINTS)


class JointCheck:
    r"""The joints' balances against one another, window by window.

    With :math:`v_j = k/I_j + s^2 + s_j^2` (:data:`~.settings.JOINT_INFO_INFLATION`: neighbouring
    windows share their noise; the calibration's model std and each joint's,
    :data:`~.settings.JOINT_MODEL_SHARE`) and :math:`\bar m` the :math:`1/v_j`-weighted mean of
    the joints' estimates :math:`m_j = N_j/I_j`, :math:`\chi^2 = \sum_j (m_j - \bar m)^2 / v_j`
    beyond :data:`~.settings.JOINT_CHI2` on :data:`~.settings.JOINT_SAMPLES` windows in a row
    fails the check (it clears after as many in a row within). The joint named is the one that
    stands out most from the mean of the others; it is named alone when the other two then agree
    (χ² of 1 dof within the limit), and :attr:`degraded` is then the weighing without it. With
    two joints compared, or when the rest disagree too, all are named and nothing is weighed. A
    named joint stays named until it agrees again with another compared joint (a new load, which
    the fault itself may trigger, restarts the sums, not the fault; a pair named before a new load
    clears also when the joints compared on that load's sums agree: :attr:`named_before_load`). A new fault is held while the
    kernel says the load is changing or the check pauses, unless its joint leads the weighing
    (:meth:`_leads`), while its one joint moves the weighing by little (:meth:`_slight`), and while
    the bucket crossed its regressor's zero and agrees on one side (:meth:`_side_agrees`). After
    a dump, a joint that weighs less than before it restarts the weighing (:meth:`_dumped_load`:
    :attr:`restart`, as when a named joint clears), and so does a pause that ends with the
    memories agreeing again (:attr:`pause_restarts`).

    Parameters
    ----------
    rated : float
        The machine's rated payload, kg.
    model_std : float
        The calibration's cross-validated model std, kg.
    """

    def __init__(self, rated: float, model_std: float):
        self.extra = float(model_std) ** 2 + (JOINT_MODEL_SHARE * float(rated)) ** 2
        # I_j of a joint compared (and of the two an ok estimate needs): its σ, inflated as in
        # v_j, within JOINT_CHECKED_SHARE of the rated payload
        self.enough = JOINT_INFO_INFLATION / (JOINT_CHECKED_SHARE * float(rated)) ** 2

        self.change_min = JOINT_CHANGE_SHARE * float(rated)
        self.moving_limit = JOINT_MOVING_SHARE * float(rated)
        self.slight_limit = JOINT_SLIGHT_SHARE * float(rated)
        self.reset()

    def reset(self) -> None:
        """Start again: no sums, no fault, no pause."""
        self.num = [0.0, 0.0, 0.0]  # the check's own sums of each joint's share
        self.info = [0.0, 0.0, 0.0]
        self.fault = ""  # "signal:balance,..." while the check fails
        self.named: tuple = ()
        self.degraded = (math.nan, 0.0)  # (estimate, information) without the joint named
        self.chi2 = 0.0
        self.checked = False  # two joints weighed well enough to check one another
        self.run = 0  # windows in a row beyond (or, while failing, within) the limit
        self.paused = 0  # windows of the current pause (0: not paused)
        self.armed = True  # a pause may start (again only once no joint is off)
        self.loads = 0  # the kernel's new loads seen
        self.dumping = False  # the bucket dumps (the kernel's dumping): its windows are not summed
        # each joint's share of the check's sums gathered since the last dump ended (same λ): the sums
        # before it are the rest (_dumped_load)
        self.after_num = [0.0, 0.0, 0.0]
        self.after_info = [0.0, 0.0, 0.0]
        self.dumped = False  # a dump since the check's sums started
        self.dumped_loads = 0  # restarts of the weighing by _dumped_load since the last reset
        self.pause_restarts = 0  # ... and at a pause's end since the last reset
        # the whole weighing N / I of the last JOINT_MOVING_WINDOWS + 1 windows (NaN: none), a ring
        self.history = [math.nan] * (JOINT_MOVING_WINDOWS + 1)
        self.history_info = [0.0] * (JOINT_MOVING_WINDOWS + 1)  # ... and its information I, a ring
        self.slot = 0  # the ring's slot the next window writes
        self.moving = False  # N / I moved by more than moving_limit over JOINT_MOVING_WINDOWS windows
        self.moved_settled = False  # ... while its last windows held at most LONE_YOUNG_SHARE of I
        # each joint's share of the check's sums from windows whose regressor φ_j < 0 (the rest: φ_j > 0),
        # same λ (_side_agrees)
        self.neg_num = [0.0, 0.0, 0.0]
        self.neg_info = [0.0, 0.0, 0.0]
        # a pair (or all three) named before the current load: the new load's sums may clear it
        self.named_before_load = False
        self.cleared_pairs = 0  # pairs cleared so on a new load's sums since the last reset
        self.side_holds = 0  # windows a new fault was held by _side_agrees alone since the last reset
        # a named fault has cleared (the kernel's sums hold the fault), or a load left in a dump
        # (_dumped_load), or a pause ended: the kernel restarts the weighing
        self.restart = False

    def update(self, kernel, d_num: list, d_info: list, d_negative=None) -> None:
        """One balance window, after the kernel has accumulated it.

        Parameters
        ----------
        kernel : CalibratedKernel
            The kernel (its whole and short sums, ``changing``, ``new_loads``, ``forgetting``).
        d_num : list
            The window's w φ r of each joint (boom, dipper, bucket).
        d_info : list
            The window's w φ² of each joint.
        d_negative : list of bool, optional
            Whether each joint's regressor φ is negative in this window (None: none is).
        """
        lam = kernel.forgetting
        if kernel.new_loads != self.loads:  # the weighing restarted: so do the check's sums
            self.loads = kernel.new_loads
            self._resume()
            # a pair named (nothing weighed) is judged again on the new load's sums (:meth:`_judge`)
            self.named_before_load = len(self.named) > 1
        self._track_moving(kernel)
        self.dumping = kernel.dumping
        if self.dumping:  # the load leaves: what the joints weigh now is no one load (not summed)
            self.dumped = True
            self.after_num, self.after_info = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
            self._judge(kernel)
            return
        n, i = self.num, self.info
        an, ai = self.after_num, self.after_info
        for j in range(3):
            n[j] = lam * n[j] + d_num[j]
            i[j] = lam * i[j] + d_info[j]
            an[j] = lam * an[j] + d_num[j]
            ai[j] = lam * ai[j] + d_info[j]
            negative = d_negative is not None and d_negative[j]
            self.neg_num[j] = lam * self.neg_num[j] + (d_num[j] if negative else 0.0)
            self.neg_info[j] = lam * self.neg_info[j] + (d_info[j] if negative else 0.0)
        if self.dumped and self._dumped_load():
            # a load left in the dump, too little for the new-load test: the weighing starts again
            # (the kernel restarts it, as after a named joint clears; the check's sums follow)
            self.restart = True
            self.dumped_loads += 1
            self._resume()
            return
        ended = False  # a pause ends on this window
        if self._load_moves(kernel):
            if self.armed and (not self.paused or d_info[0] + d_info[1] + d_info[2] > 0.0):
                self.paused += 1  # it lasts so many windows with information, not of standstill
                if self.paused > JOINT_PAUSE_WINDOWS:  # a lasting difference: judged on the sums
                    self.paused = 0
                    self.armed = False
        else:
            self.armed = True
            if self.paused:
                self._resume()
                ended = True
        self._judge(kernel)
        if ended and PAUSE_RESTARTS and not getattr(kernel, "substituting", False):
            # the weighing's sums still hold the windows of what the pause saw (a load change too
            # small for the new-load test, or a fault that moved the weighing): it starts again
            # as the check's sums did (a boom rod pressure 12 bar low for 0.7 s: ok 61 kg off after
            # it, the check's fresh sums agreeing; docs/sensor-health.md, session 21); not while the
            # weighing runs on the monitor's substitutes: it would start again on them alone
            self.restart = True
            self.pause_restarts += 1

    def _track_moving(self, kernel) -> None:
        """:attr:`moving`: the whole weighing reported against its value
        :data:`JOINT_MOVING_WINDOWS` windows back (a NaN on either side: not moving): N / I, or
        with ``--imu-nuisance on`` the filter's payload as the last window left it (it moves up
        to 4× faster than N / I: a dipper head pressure 29 % low, 65 kg ``ok`` while N / I had
        moved 14 kg, docs/sensor-health.md). :attr:`moved_settled`: it moved while the windows of
        the ring held at most :data:`~.settings.LONE_YOUNG_SHARE` of the weighing's information I
        (a new load's first second converges: no lone joint's fault, docs/loadout.md)."""
        n = JOINT_MOVING_WINDOWS + 1
        if kernel.info > 0.0:  # the weighing reported (with --imu-nuisance the filter's, one window late)
            nuisance = getattr(kernel, "_imu_nuisance", None) is not None
            now = getattr(kernel, "payload_before", math.nan) if nuisance else kernel.num / kernel.info
        else:
            now = math.nan
        oldest = (self.slot + 1) % n
        then, info_then = self.history[oldest], self.history_info[oldest]  # NaN until the ring is full
        self.history[self.slot], self.history_info[self.slot] = now, kernel.info
        self.slot = (self.slot + 1) % n
        self.moving = abs(now - then) > self.moving_limit
        self.moved_settled = self.moving and 0.0 < kernel.info and info_then >= (1.0 - LONE_YOUNG_SHARE) * kernel.info

    @property
    def suspect(self) -> bool:
        """Whether the whole weighing moves (:attr:`moving`) while the load-change test sees one
        load: a fault not yet named (or a load change not yet seen); not ``ok``
        (``load_changing``) until it holds still."""
        return self.moving

    def _resume(self) -> None:
        self.paused = 0
        self.num, self.info = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self.after_num, self.after_info = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self.neg_num, self.neg_info = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self.dumped = False

    def _dumped_load(self) -> bool:
        """Whether one joint, weighed both before the last dump and after it (each part compared on
        its own: I within :data:`~.settings.JOINT_CHECKED_SHARE`), weighs less after it by more than
        :data:`~.settings.JOINT_CHANGE_SHARE` of the rated payload and beyond
        :data:`~.settings.JOINT_CHI2` with the check's variances of both parts: a load left in the
        dump. A constant sensor fault biases a joint before a dump and after it alike (up to its
        lever at the two poses), and a dump takes load away, never adds it; a load too small
        for the new-load test otherwise leaves the joints that stand after the dump with the old
        load's sums and the one that moves weighing the emptier bucket (the stale joint,
        docs/findings/false-alarms.md)."""
        for j in range(3):
            after = self.after_info[j]
            before = self.info[j] - after
            if after < self.enough or before < self.enough:
                continue
            drop = (self.num[j] - self.after_num[j]) / before - self.after_num[j] / after
            if drop > self.change_min and \
                    drop * drop > JOINT_CHI2 * (JOINT_INFO_INFLATION / after + JOINT_INFO_INFLATION / before + self.extra):
                return True
        return False

    def _load_moves(self, kernel) -> bool:
        """Whether the load changes as the check sees it: the new-load test's short memory has
        left the whole weighing by :data:`~.settings.JOINT_CHANGE_SHARE` of the rated payload
        and :data:`~.settings.CHANGING_SIGMAS` of the difference's σ (1 / I inflated as the
        check's)."""
        if not 0.0 < kernel.info_short < kernel.info:
            return False
        spread = JOINT_INFO_INFLATION * max(1.0 / kernel.info_short - 1.0 / kernel.info, 0.0)
        change = abs(kernel.num_short / kernel.info_short - kernel.num / kernel.info)
        return change > max(self.change_min, CHANGING_SIGMAS * math.sqrt(spread))

    @property
    def pausing(self) -> bool:
        """Whether the check pauses (a joint sees the load change): the kernel says ``load_changing``."""
        return self.paused > 0

    def _judge(self, kernel) -> None:
        nj, ij, extra = self.num, self.info, self.extra
        joints = [j for j in range(3) if ij[j] >= self.enough]
        chi2 = 0.0
        m, w = {}, {}
        if len(joints) >= 2:
            m = {j: nj[j] / ij[j] for j in joints}
            w = {j: 1.0 / (JOINT_INFO_INFLATION / ij[j] + extra) for j in joints}
            chi2 = _spread(joints, m, w)
        self.chi2 = chi2
        self.checked = len(joints) >= 2
        failing = chi2 > JOINT_CHI2
        # the load is changing: the joints that move see it first; a new fault waits (its run
        # goes on: named at once if the joints still disagree when the pause ends)
        # nor while the bucket dumps or before the weighing is ready (a new load's first windows:
        # the fill, a dig), whichever joint leads
        # nor while the one joint it would name moves the weighing by less than the model error the
        # check allows a joint (_slight: its own model error as likely as a sensor)
        held = failing and not self.fault and (self.dumping or not kernel.ready or (kernel.changing or self.paused > 0)
                                               and not self._leads(joints, m, w) or self._slight(joints, m, w))
        # nor while the joint crossed (φ_j of both signs) and weighed on one side agrees (_side_agrees)
        sided = failing and not self.fault and not held and self._side_agrees(joints, m, w)
        self.side_holds += sided
        held = held or sided
        if self.fault and not failing and not (len(joints) >= 2 and (set(self.named) <= set(joints)
                                                                     or self.named_before_load)):
            # a named joint is cleared only by agreeing with another compared joint (a pair: its
            # own two agreeing again); a pair named before the current load also by the joints
            # compared on that load's sums agreeing (any two of the three hold one of the pair; the
            # other may never be compared again: a dig's bucket, docs/findings/false-alarms.md)
            failing = True
        if failing != bool(self.fault):
            self.run += 1
        else:
            self.run = 0
        if self.run < JOINT_SAMPLES or held:
            if self.fault and len(self.named) == 1:
                self.degraded = kernel._without(self.named[0])
            return
        self.run = 0
        if not failing:
            # the whole weighing still holds the windows the fault biased: it starts again
            self.restart = bool(self.fault)
            self.cleared_pairs += self.named_before_load
            self.fault, self.degraded, self.named = "", (math.nan, 0.0), ()
            self.named_before_load = False
            return
        self._name(_named(joints, m, w))
        self.degraded = kernel._without(self.named[0]) if len(self.named) == 1 else (math.nan, 0.0)

    def _name(self, named) -> None:
        self.named = tuple(named)
        self.named_before_load = False
        self.fault = ",".join(f"{s}:balance" for j in named for s in JOINT_PRESSURES[j])

    def _leads(self, joints: list, m: dict, w: dict) -> bool:
        """Whether the one joint the check would name holds more information than the joints it
        disagrees with: then the whole weighing follows it, and a load change the kernel sees
        is that joint's doing, not one the joints that move see first."""
        named = _named(joints, m, w)
        return len(named) == 1 and 2.0 * self.info[named[0]] > sum(self.info[j] for j in joints)


    def _slight(self, joints: list, m: dict, w: dict) -> bool:
        """Whether the one joint the check would name moves the weighing on the check's sums (N / I
        of the compared joints against the same without it) by at most
        :data:`~.settings.JOINT_SLIGHT_SHARE` of the rated payload."""
        named = _named(joints, m, w)
        if len(named) != 1:
            return False
        rest = [j for j in joints if j != named[0]]
        whole = sum(self.num[j] for j in joints) / sum(self.info[j] for j in joints)
        without = sum(self.num[j] for j in rest) / sum(self.info[j] for j in rest)
        return abs(whole - without) <= self.slight_limit

    def _side_agrees(self, joints: list, m: dict, w: dict) -> bool:
        """Whether the one joint the check would name, one of :data:`~.settings.SIDE_JOINTS`, holds
        windows of both signs of its regressor φ_j (each side's information > 0) and, weighed on
        one side's sums alone (a side compared only with I within
        :data:`~.settings.JOINT_CHECKED_SHARE`), agrees with the other compared joints (χ² within
        :data:`~.settings.JOINT_CHI2`)."""
        named = _named(joints, m, w)
        if len(named) != 1:
            return False
        j = named[0]
        if not SIDE_JOINTS[j]:
            return False
        sides = ((self.num[j] - self.neg_num[j], self.info[j] - self.neg_info[j]),
                 (self.neg_num[j], self.neg_info[j]))
        if not (sides[0][1] > 0.0 and sides[1][1] > 0.0):
            return False
        for n_side, i_side in sides:
            if i_side < self.enough:
                continue
            ms, ws = dict(m), dict(w)
            ms[j], ws[j] = n_side / i_side, 1.0 / (JOINT_INFO_INFLATION / i_side + self.extra)
            if _spread(joints, ms, ws) <= JOINT_CHI2:
                return True
        return False


def _spread(joints: list, m: dict, w: dict) -> float:
    """χ² of the joints' weighings about their weighted mean: Σ w_j (m_j − m̄)²."""
    mean = sum(w[j] * m[j] for j in joints) / sum(w[j] for j in joints)
    return sum(w[j] * (m[j] - mean) ** 2 for j in joints)


def _named(joints: list, m: dict, w: dict) -> list:
    """The joints a failing check names: the one that stands out most from the mean of the
    other two, alone when those two then agree; else every compared joint."""
    if len(joints) != 3:
        return joints

    def stands_out(j):  # (m_j − mean of the others)² over its variance, and the others
        rest = [i for i in joints if i != j]
        w_rest = sum(w[i] for i in rest)
        mean_rest = sum(w[i] * m[i] for i in rest) / w_rest
        return (m[j] - mean_rest) ** 2 / (1.0 / w[j] + 1.0 / w_rest), rest

    worst = max(joints, key=lambda j: stands_out(j)[0])
    a, b = stands_out(worst)[1]
    if (m[a] - m[b]) ** 2 / (1.0 / w[a] + 1.0 / w[b]) <= JOINT_CHI2:
        return [worst]
    return joints
