"""The machine-set calibration's names in one place (its rooms are :mod:`.machine_calibration`).

Code written against ``calibrated_machine`` keeps working: every public name of the rooms
(settings, symbolic residuals, data preparation, solver, kernel, the estimator's side) is
re-exported here. New code imports from the room itself. What a ``calibrated`` estimator holds
on the machine sensor set, with its save and restore, is its kernel
(:class:`~excavator_payload.estimators.classical.calibrated.WeighingKernel`).
"""

from __future__ import annotations

from excavator_payload.estimators.classical.machine_calibration.data import (  # noqa: F401
    _glitches, _window_sums, accel_variance, accelerations, angle_coverage, balance_weights,
    calibration_arrays, held_direction, house_imu_sensitivity, imu_sensitivities, momentum_windows,
    pressure_noise_from_data, rate_variance, window_residuals)
from excavator_payload.estimators.classical.machine_calibration.kernel import CalibratedKernel  # noqa: F401
from excavator_payload.estimators.classical.machine_calibration.settings import (  # noqa: F401
    _OFFSET_COLUMNS, _PARAM_INDEX, BALANCE_CHOICES, BALANCE_HALF_WINDOW, BALANCE_RAMP, CALIBRATED_PARAMETERS,
    CALIBRATION_HALF_WINDOW, CHANGING_MIN_SHARE, CHANGING_SIGMAS, COVERAGE_JOINTS, COVERAGE_MARGIN,
    COVERAGE_PERCENTILES, DEFAULT_PRESSURE_STD, DEG, FRICTION_PARAMETERS, GLITCH_SIGMAS, HELD_IN_MOMENTUM,
    HELD_SAMPLES, IMU_LEAK_CHOICES, IMU_PARAMETERS, IMU_PRIOR_STD, LOW_SPEED_CHOICES, MAX_CALIBRATION_VALUE,
    MIN_CROSS_EXPERIMENTS, MIN_MOVING_SAMPLES, MIN_ZERO_MOVING_SAMPLES, NEW_LOAD_CHOICES, NEW_LOAD_MEMORY,
    NEW_LOAD_MIN_SHARE, NEW_LOAD_SIGMAS, NO_LIMIT, OFFSET_PRIOR_STD, OFFSET_SIGNALS, OUTSIDE_CALIBRATION_CHOICES,
    SIGMA_COVERAGE, SIGNALS, WAIT_FOR_BOOM_CHOICES, ZERO_OFFSET_CHI2)
from excavator_payload.estimators.classical.machine_calibration.solver import (  # noqa: F401
    MachineCalibration, calibrate, cross_validated_model_std, zero_offsets)
from excavator_payload.estimators.classical.machine_calibration.symbolic import (  # noqa: F401
    _corrected_signals, _momentum_terms, _unpack, compiled, house_imu_leak, kernel_function,
    momentum_function, residual_function)
from excavator_payload.estimators.classical.machine_calibration.weighing import (  # noqa: F401
    MachineWeighing, coverage_notes, hardly_moved, machine_arm, waiting_notes, zero)
from excavator_payload.estimators.classical.pressure_regression import (  # noqa: F401
    ANGLES, PITCH, PRESSURES, RATES, ROLL)

