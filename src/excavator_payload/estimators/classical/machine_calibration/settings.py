"""Settings of the machine-set calibration: what it identifies, its priors, windows and choices.

The unknowns are :math:`z = (\\delta, o, \\iota)`: relative deviations :math:`\\delta` of the
machine file's :data:`CALIBRATED_PARAMETERS`, the sensor offsets :math:`o` of
:data:`OFFSET_SIGNALS` and the IMU dynamics :math:`\\iota` (:data:`IMU_PARAMETERS`), with the
priors :data:`OFFSET_PRIOR_STD` and :data:`IMU_PRIOR_STD`. The ``--option`` choices of the
``calibrated`` estimator on the machine sensor set are here too. What each choice measured is in
``docs/findings/machine-weighing.md`` ("Calibration settings").
"""

from __future__ import annotations

import math

import numpy as np

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.model.hydraulic import CYLINDERS, HYDRAULIC_PARAMETER_NAMES

SIGNALS = MACHINE_SENSORS.signals
DEG = math.pi / 180.0

#: Physical parameters calibration adjusts (relative deviation from the machine file).
CALIBRATED_PARAMETERS: tuple[str, ...] = (
    "boom_length", "dipper_length", "boom_foot_x", "boom_foot_z",
    *(f"{link}_{k}" for link in ("boom", "dipper", "bucket")
      for k in ("mass", "com_u", "com_w", "inertia_u", "inertia_y", "inertia_w")),
    "payload_u", "payload_w",
    "boom_cylinder_parent_x", "boom_cylinder_parent_z", "boom_cylinder_child_u", "boom_cylinder_child_w",
    "dipper_cylinder_parent_u", "dipper_cylinder_parent_w", "dipper_cylinder_child_u",
    "dipper_cylinder_child_w", "bucket_cylinder_parent_u", "bucket_cylinder_parent_w",
    "rocker_pivot_u", "rocker_pivot_w", "rocker_length", "link_length", "bucket_point_u", "bucket_point_w",
    *(f"{c}_{k}" for c in CYLINDERS for k in ("head_area", "rod_area", "coulomb", "load_coefficient",
                                               "viscous")),
)
#: Friction parameters among them (nuisances of the Cramér–Rao bound).
FRICTION_PARAMETERS = tuple(p for p in CALIBRATED_PARAMETERS
                            if p.endswith(("coulomb", "load_coefficient", "viscous")))
#: Parameters the momentum form's calibration holds at the machine file: where the arm stands
#: relative to the slew axis. Moving the boom foot together with the boom cylinder's base is
#: invisible in the arm's own balance (vertically not at all, horizontally only through the
#: slewing's centrifugal terms), so a free fit moves both to absorb what it cannot model. Held
#: at the file (a drawing dimension), the cylinder base, whose position relative to the foot
#: sets the boom's moment arm, stays free (findings: "Held in the momentum form").
HELD_IN_MOMENTUM = ("boom_foot_x", "boom_foot_z")
#: Signals with an estimated offset (zero), in this order.
OFFSET_SIGNALS: tuple[str, ...] = (
    *(s for s in SIGNALS if s.endswith("_pressure")), "boom_angle", "dipper_angle", "bucket_angle",
    "house_pitch", "house_roll")
#: Prior std of each offset (the field preset's session offsets), SI units.
OFFSET_PRIOR_STD = np.array([1.5e5] * 6 + [0.1 * DEG] * 3 + [0.1 * DEG] * 2)
#: The IMUs' dynamic error, identified in calibration: output lag τ (s) and each inclination
#: IMU's sensitivity to its link's tangential acceleration (s²: tilt error per rad/s² of the
#: link's absolute angular acceleration; the house IMU's per (rad/s)² centripetal and rad/s²
#: tangential slew acceleration).
IMU_PARAMETERS: tuple[str, ...] = ("imu_lag", "boom_imu_acceleration_sensitivity",
                                   "dipper_imu_acceleration_sensitivity",
                                   "bucket_imu_acceleration_sensitivity",
                                   "house_imu_acceleration_sensitivity")
#: Their prior: mean 0, std 20 ms (MEMS IMU output filters: a few to tens of ms) and, for the
#: sensitivities, a 5 % fusion leak at the IMU's distance d from its axis, 0.05 · d / g: a link
#: IMU up to 4 m from its joint, 0.02 s²; the house IMU (pitch and roll) within 1 m of the slew
#: axis, where inclination sensors go, 0.005 s² (with the links' 0.02 s² it absorbed the rates'
#: noise instead: findings, "The house IMU's prior").
IMU_PRIOR_STD = np.array([0.02, 0.02, 0.02, 0.02, 0.005])
#: ``--imu-nuisance on``: the IMU dynamics re-estimated per load while weighing (momentum form,
#: :mod:`.imu_nuisance`), the calibration's posterior as prior: the lag and the house IMU's
#: sensitivity (the link IMUs' add nothing: docs/findings/nuisance-oracle.md).
IMU_NUISANCES: tuple[str, ...] = ("imu_lag", "house_imu_acceleration_sensitivity")
#: Choices of ``--imu-nuisance`` (``auto``: on in the momentum form, with or without the joint
#: check — :func:`.weighing.imu_nuisance_on`; measured on held-out draws:
#: docs/findings/nuisance-oracle.md, "On by default").
IMU_NUISANCE_CHOICES = ("auto", "on", "off")
#: Moving samples per cylinder below which fit warns that calibration learned little of it
#: (2 s at 100 Hz).
MIN_MOVING_SAMPLES = 200
#: The same for one cylinder in the zero check (1 s at 100 Hz).
MIN_ZERO_MOVING_SAMPLES = 100
#: ``zero`` refuses a motion whose boom angle travels less than this (rad; the 2nd to 98th
#: percentile of its measured angle): its offsets take up the model's error at that one boom
#: pose. Tuning (calibration draws of seeds 140000-144999): empty multi-sine motions moved the
#: boom 4-11° and weighed a family worse than 1 % of rated after 2 of 16 zeros (worst MAX
#: 121 kg); every other accepted empty motion moved it 22° or more and weighed within 1 %
#: (findings: "Which empty motions a zero accepts").
MIN_ZERO_BOOM_TRAVEL = 15.0 * DEG
#: ``zero`` refuses offsets whose sum of squares in prior standard deviations
#: (:data:`OFFSET_PRIOR_STD`, a working session's drift) exceeds this: χ² of the 11 offsets at
#: 10⁻⁶ (37.4 at 10⁻⁴). Clean zero checks on 62 empty motions (swings, slow one-lever moves, joystick passes, 5°
#: and 8° slopes; 5 calibration draws, 10 sessions) gave 1.3–16.3; a load left in the bucket
#: is taken for offsets (300 kg: 73–333, 1000 kg: 650–3500), a stuck or mis-scaled signal goes
#: far beyond (findings: "Zero offset check").
ZERO_OFFSET_CHI2 = 48.9
#: Choices of ``--low-speed``.
LOW_SPEED_CHOICES = ("model", "downweight", "skip")
#: Choices of ``--outside-calibration``: what becomes of a joint's window where the joint's angle
#: lies outside the range the calibration motions covered. ``skip``: the bucket joint gets no
#: weight there (:data:`COVERAGE_JOINTS`); ``arm``: while any of boom, dipper or bucket lies
#: outside its covered range, no joint gets weight (the arm's pose was not calibrated: every
#: joint's balance carries the links beyond it); ``use``: weighed anyway. ``auto``: ``skip`` in
#: the momentum form, ``use`` in the per-sample form (whose boom and dipper alone, through the
#: differentiator, are worse than its extrapolated bucket).
OUTSIDE_CALIBRATION_CHOICES = ("auto", "skip", "arm", "use")
#: Choices of ``--wait-for-boom``: report no estimate until the boom joint has been weighed
#: (a 0.5 s window of boom motion). ``auto``: ``yes`` in the momentum form, ``no`` in the
#: per-sample form.
WAIT_FOR_BOOM_CHOICES = ("auto", "yes", "no")
#: With ``--wait-for-boom``, windows that weigh the boom before an estimate is reported (0.5 s
#: of boom motion): with one window the first ``ok`` estimates rested on the motion's start
#: alone and erred most (findings: any-motion, "The boom's first windows").
BOOM_READY_WINDOWS = 50
#: With ``--wait-for-boom``, once the boom's windows are in: an estimate is reported when it holds
#: still, having moved by at most :data:`STEADY_SHARE` of the rated payload over the last
#: :data:`STEADY_WINDOWS` windows (0.5 s), and from then on until the weighing restarts. The
#: first estimates after a start rest on the motion's acceleration, where what a calibration got
#: wrong (an IMU lag, friction at breakaway) weighs most, and drift towards the weight as the
#: motion goes on (findings: any-motion, "A weight that holds still").
STEADY_WINDOWS = 50
#: The most a steady estimate moves over :data:`STEADY_WINDOWS` windows, share of the rated payload.
STEADY_SHARE = 0.001
#: Choices of ``--new-load``: restart the weighing when the load changes (a dump, a new bucket
#: load on a machine that weighs one load after another). ``auto``: ``detect`` in the momentum
#: form, ``off`` in the per-sample form.
NEW_LOAD_CHOICES = ("auto", "detect", "off")
#: Choices of ``--imu-leak``: where the three link IMUs' acceleration sensitivities come from.
#: ``signals``: read off each IMU's own angle and rate (``imu_sensitivities``) and held in
#: calibration, zero and weighing; ``fit``: identified in the calibration fit with the other
#: parameters; ``none``: not modelled (0); ``auto`` (the default): ``signals`` in the momentum
#: form, ``fit`` in the per-sample form. The house IMU's is fitted in the per-sample form and
#: left out of the momentum form whatever the choice.
IMU_LEAK_CHOICES = ("auto", "signals", "fit", "none")
#: The new-load test compares the estimate of a short memory (exponential, this time constant,
#: s) with the whole weighing's ...
NEW_LOAD_MEMORY = 1.0
#: ... and takes a difference of more than this share of the rated payload, and more than
#: :data:`NEW_LOAD_SIGMAS` standard deviations of the difference, for a new load.
NEW_LOAD_MIN_SHARE = 0.1
NEW_LOAD_SIGMAS = 5.0
#: Before a new load is certain, a short memory leaving the whole one by both
#: :data:`CHANGING_SIGMAS` and :data:`CHANGING_MIN_SHARE` of the rated payload says the load is
#: changing (status ``load_changing``): while the bucket dumps, the whole memory still holds the
#: load before, and calling it ``ok`` reported the old load for the 1-3 s the restart test needs.
CHANGING_MIN_SHARE = 0.05
CHANGING_SIGMAS = 5.0
#: A ``load_changing`` episode of at least this many windows that ends without a new load
#: (the two memories agree again) sets the whole memory to the short one: a restart while the
#: bucket still fills, or a change too small for a new load, leaves the change's windows in
#: the whole memory, where they stay for seconds (a pass locked at 3310 kg for 3454 kg).
SETTLE_WINDOWS = 25
#: The joint consistency check (a wrong pressure biases only its own joint's balance; set on
#: clean tuning data of one seed, docs/sensor-health.md): each joint's estimate N_j / I_j is
#: judged about their weighted mean with variance k / I_j + the calibration's model std² +
#: (this share of the rated payload)², each joint's own model error (25 kg: the clean tuning
#: data's per-joint error beyond its σ reaches 93 kg; with 10 kg their χ² reached 17, with 25 kg
#: 6.6, the first design's margin to the threshold) ...
JOINT_MODEL_SHARE = 0.005
#: ... and 1 / I_j counts as this many times its value: the momentum balance's windows slide by
#: one sample, so neighbouring windows share their noise and I_j counts it many times over
#: (clean tuning data: single joints up to 11 σ = I_j^-1/2 off) ...
JOINT_INFO_INFLATION = 9.0
#: ... the joints disagree when χ² of their estimates about the mean exceeds this ...
JOINT_CHI2 = 15.0
#: ... on this many samples in a row (a window's transient is not a sensor), and the fault
#: clears after as many in a row below it.
JOINT_SAMPLES = 10
#: Before a fault is named, no estimate is ``ok`` (it says ``load_changing``) while the whole
#: weighing N / I has moved by more than this share of the rated payload over the last
#: :data:`JOINT_MOVING_WINDOWS` windows: one load weighs still. Clean tuning data (seeds 9300 and
#: 62000, ten families) move at most 12.5 kg in 0.2 s where the estimate is within 1 % of rated;
#: a boom rate 20-30 % off moved it 45 kg in 0.11 s while the joints' χ² stayed below 5
#: (docs/sensor-health.md, "Before the name, and after"). A χ² limit below the naming one was
#: tried and dropped: clean lever motions on a slope reach χ² 15.7 with the estimate 4 kg off.
JOINT_MOVING_SHARE = 0.003
JOINT_MOVING_WINDOWS = 20
#: A move (:data:`JOINT_MOVING_SHARE`) makes a joint weighed alone wait for a second one only once
#: the weighing is settled: its last :data:`JOINT_MOVING_WINDOWS` windows hold at most this share
#: of its information. A new load's first second converges by more than the moving limit with the
#: boom alone (fresh shifts 5151/6161/7171: 15-120 kg in 0.2 s while those windows held 13-25 % of
#: the information; 0.9-12.8 of the weighing's σ, so no σ test parts them), and the pass then
#: waited to the dump (``warming_up``); a fault moves a weighing that holds much already.
LONE_YOUNG_SHARE = 0.1
#: A new fault of one joint is held while the weighing without that joint (on the check's sums)
#: lies within this share of the rated payload of the weighing with it: a joint that holds so
#: little of the information that it moves the weighing by less than the check's own allowance
#: for one joint's model error (:data:`JOINT_MODEL_SHARE`, 25 kg) is as likely that model error at
#: poses the calibration did not cover as a sensor (clean `multisine` motions of fresh
#: calibrations: the dipper 177 kg off the others on 2-5 % of the information, the weighing
#: 4-9 kg off; clean sloped swings, tuning seeds 94300/95000: the dipper +97/+141 kg off on 8-12 %,
#: the weighing 14-16 kg off; was :data:`JOINT_MOVING_SHARE`, 15 kg; docs/findings/false-alarms.md).
JOINT_SLIGHT_SHARE = JOINT_MODEL_SHARE
#: The joints whose new fault is held while they crossed their regressor's zero and one side of it
#: agrees with the others (``JointCheck._side_agrees``): the bucket only, whose lever to the load is
#: short (the load's place in it weighs most where it sits near over the pin; the braked end of a
#: curl, docs/findings/false-alarms.md). With the dipper too, an offset of a held-out `lever` cycle's
#: dipper rod pressure went unnamed (bench_faults --n 3 --seed 83400).
SIDE_JOINTS = (False, False, True)
#: The check pauses while the new-load test's short memory has left the whole weighing by this
#: share of the rated payload (and CHANGING_SIGMAS): a dump, which the joints that move see
#: first while a standing boom keeps the whole weighing where it was (the load_changing test's
#: 5 % came 2 s late on the tuning slopes) ...
JOINT_CHANGE_SHARE = 0.02
#: ... at most this many windows that weigh anything (a lasting fault can keep the memories
#: apart: the check then judges on its sums); a pause that ends before starts it from nothing.
JOINT_PAUSE_WINDOWS = 200
#: The joint check's pause (:data:`JOINT_CHANGE_SHARE`) that ends with the memories agreeing again
#: restarts the weighing, as the check's own sums: the whole sums still hold the windows the pause
#: saw (a load change too small for the new-load test, or a sensor fault that moved the weighing:
#: a boom rod pressure 12 bar low for 0.7 s came out ``ok`` 61 kg off, a boom rate's bias in the
#: warm-up 56 kg; docs/sensor-health.md, session 21).
PAUSE_RESTARTS = True
#: The bucket dumps while it opens faster than this (rad/s): a load leaves only then, and the
#: joints that move see it leave before the standing ones. Until the bucket has opened no faster
#: for :data:`DUMP_HOLD` s the check names nothing new and does not sum the windows: what the
#: joints weigh during a dump is no one load. Set on the tuning seed's
#: dumps (30 slopes work cycles, 6 truck loadings; docs/sensor-health.md): with 40 °/s and 1.2 s
#: every balance window that overlaps a release is a dump's (50 °/s: 71 of 9 200 were not, the
#: slow dumps' first windows and the tails); its operator motions open that fast in 0.12 % of
#: samples.
DUMP_OPENING_RATE = math.radians(40.0)
DUMP_HOLD = 1.2
#: With ``--new-load detect``: a dump says ``load_changing`` and its end (:data:`DUMP_HOLD` after
#: the bucket's last fast opening) restarts the weighing, as a new load. Before, a dump's windows
#: stayed in the sums until the new-load test saw the change once the boom moved again: a slopes
#: cycle's emptied bucket was ``ok`` at the load before it for 2 s (881 kg) and the emptied
#: bucket's first weights erred up to 86 kg (docs/findings/false-alarms.md, session 19).
DUMP_RESTARTS = True
#: ... when the weighing held more than this share of the rated payload as the bucket began to
#: open (or was not ready): a load a dump can leave (the joint check's JOINT_CHANGE_SHARE); an
#: empty bucket opened fast to set the next cut is no dump.
DUMP_LOAD_SHARE = 0.02
#: ... and when the bucket has opened by more than this since it began to open fast (rad): it
#: turns over and the load slides out. Set on the tuning seed's motions (bench_false_alarms,
#: seed 40000): dumps open 57-117° (slopes, shift), while an operator's or a joystick's quick
#: bucket moves with the load kept open 2-14° and a work cycle's bucket up to its release 9-20°.
DUMP_TURN = math.radians(30.0)
#: A joint is compared only once its σ, (JOINT_INFO_INFLATION / I_j)^½, is within this share of
#: the rated payload (an early joint on little information stood 115 kg off on a clean swing),
#: and with the check on an estimate is ``ok`` only once two joints are compared: one joint
#: alone cannot be checked (a boom pressure 10 % off set off a new load, and the boom alone then
#: weighed 1269 kg off, ``ok``).
JOINT_CHECKED_SHARE = 0.01
#: The pressures each joint's balance carries (its cylinder's head and rod), named when it
#: stands out.
JOINT_PRESSURES = (("boom_head_pressure", "boom_rod_pressure"),
                   ("dipper_head_pressure", "dipper_rod_pressure"),
                   ("bucket_head_pressure", "bucket_rod_pressure"))
#: The covered range of each arm angle: these percentiles of the calibration samples (robust to
#: a glitch), widened by :data:`COVERAGE_MARGIN` each side (rad).
COVERAGE_PERCENTILES = (0.5, 99.5)
COVERAGE_MARGIN = 5.0 * DEG
#: The joints the range limits while weighing: the bucket, whose four-bar linkage is the model's
#: most nonlinear geometry. Boom and dipper levers extrapolate smoothly (limiting them too
#: gained nothing: findings, "Outside the calibrated range").
COVERAGE_JOINTS = (False, False, True)
#: Stands for "no limit" in the coverage (a model saved before it existed, or ``use``); finite,
#: so that the C export writes it as a number.
NO_LIMIT = 1.0e30
#: Default pressure noise before it is estimated (the field preset's), Pa.
DEFAULT_PRESSURE_STD = 3.0e4
_PARAM_INDEX = np.array([HYDRAULIC_PARAMETER_NAMES.index(n) for n in CALIBRATED_PARAMETERS])
_OFFSET_COLUMNS = np.array([SIGNALS.index(s) for s in OFFSET_SIGNALS])

#: Slow samples after the last sliding one that keep its friction direction (0.1 s): a reversal
#: or a slow pass turns the friction over through the presliding state, but once a valve has
#: closed the seal holds whatever balanced the trapped pressures, anywhere within ± breakaway.
HELD_SAMPLES = 10

#: Samples each side of the centred differentiator in calibration (0.3 s: the lifts are slow,
#: and the rate noise through a shorter window dominates the boom's residual; findings,
#: "Calibration settings").
CALIBRATION_HALF_WINDOW = 15
#: ``--balance``: how the estimator does without measured accelerations.
BALANCE_CHOICES = ("differentiated", "momentum")
#: The momentum balance's window: ±25 samples (0.5 s), its ends averaged over 10 samples
#: (``balance_weights``). The rates' noise through the momentum falls as the window grows
#: and nothing else grows with it (no differentiator bias; findings, "Calibration settings").
BALANCE_HALF_WINDOW = 25
BALANCE_RAMP = 10

#: A sample whose angle or rate jumps more than this many robust noise stds (of the second
#: difference) is a glitch to ``imu_sensitivities``: arm motion's own second differences stay
#: below 1 % of it (a jerk of 340 rad/s³ would reach it).
GLITCH_SIGMAS = 8.0

#: Share of held-out calibration samples whose error the reported σ must cover twice
#: (``cross_validated_model_std``): σ = √(1/I + s_model²) with 2σ ⊇ 95 % of them (after a zero,
#: σ = √(1/I + s_model² + s_zero²), s_zero the zero's offsets posterior as it weighs).
SIGMA_COVERAGE = 0.95
#: Fewest calibration experiments for the cross-check (two folds of at least two motions).
MIN_CROSS_EXPERIMENTS = 4
#: Folds of the second cross-check that decides a refusal when the halves weigh each other worse
#: than 1 % of rated (at most one per motion: one motion out on 5 motions); σ keeps the halves' s.
REFUSAL_FOLDS = 5
#: Share of the rated payload that the folds' 2·s must stay inside for that check to accept: half
#: the 1 % a motion's worst error is judged by, as a motion's worst error ran to about twice the
#: 2·s band (5-motion tuning draws: within 27 kg at 2·s = 15 kg; the per-sample form at
#: 2·s = 41 kg weighed a third to two thirds of the motions within 1 %).
REFUSAL_FOLDS_SHARE = 0.005

#: The largest magnitude a restored calibration ``z`` may hold (a pressure offset of 10,000
#: bar; real calibrations stay below 3e5).
MAX_CALIBRATION_VALUE = 1e9
