r"""Quasi-static payload estimator: the industry baseline (patent EP0736752A1).

As the thesis' introduction describes it, the industry's virtual sensors calibrate with slow
lifts at the *same constant angular speed*, at two reference payloads (empty and rated), over a
pre-defined range of motion, and store the boom's load (cylinder pressure; here the boom torque)
as a characteristic map over (boom angle, dipper angle) for each reference. In operation they
interpolate the measured torque linearly between the two maps:

.. math::

    \hat m_k = m_E + (m_R - m_E)\,
               \frac{\tau_{1,k} - T_E(q_{1,k}, q_{2,k})}{T_R(q_{1,k}, q_{2,k}) - T_E(q_{1,k}, q_{2,k})}

where :math:`T_E, T_R` are the empty and rated maps (bilinear interpolation on their grids) and
:math:`m_E, m_R` the reference payloads. At the calibration speed this is exact, because the
torque is affine in the payload; at any other speed (acceleration, other friction, Coriolis
terms) it is biased — the reason the thesis looks for *dynamic* estimators.

Map building (``fit``)
----------------------
Each calibration experiment must be a lift (dipper held still, boom moving). Only its
constant-speed part is used: from the first to the last sample whose boom rate is within
``--speed-tolerance`` (relative) of the lift's median rate, minus ``--trim`` seconds at both ends
(the tails of the speed ramps, where the arm still accelerates). On a boom-angle grid of ``--grid-step`` degrees over the range that
every lift covers, each lift's torque is smoothed by a local-linear fit (triangular kernel, half
width one grid step); the lines of one reference payload, ordered by their dipper angle, form its
map.

Machine sensor set
------------------
A machine measures no joint torque; as the patent does, the boom's load is the boom cylinder's
piston force :math:`F = p_h A_h - p_r A_r` (head pressure times head area minus rod pressure
times annulus area, areas from the hydraulic machine file), mapped over boom and dipper angle
from the calibration lifts (``excavator-payload simulate --machine cat345c-hydraulic --motion
lifts``) exactly as the torque is on the thesis set. Nothing else changes: the map ignores
bucket angle, slewing, tilt, accelerations and friction (what the dynamic estimators model).

Estimation (``step``)
---------------------
``--averaging cumulative`` (default) reports the running mean of the per-sample values since the
start of the experiment (what a weighing system shows at the end of a lift; comparable with the
whole-history estimators), ``none`` the per-sample value. Samples outside the map's angles are
not used (status ``out_of_range``). With ``--speed-gate true`` only samples at the calibration
speed are used (boom rate within ``--speed-tolerance`` of it, dipper rate below that tolerance),
as the patent prescribes; other samples keep the last estimate (status ``no_data`` while there
is none).
"""

from __future__ import annotations

import bisect
import math
from typing import Mapping

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Estimator, Option, Status, StepResult, register
from excavator_payload.platforms import HYDRAULIC, THESIS, platform_for

DEG = math.pi / 180.0
#: Calibration lifts whose dipper angles differ by less than this share one map line, rad.
DIPPER_MERGE = 0.5 * DEG
#: Fewer map lines (dipper angles) than this per reference payload get a warning at fit.
MIN_MAP_LINES = 3


def local_linear(x: np.ndarray, y: np.ndarray, nodes: np.ndarray, half_width: float) -> np.ndarray:
    r"""Local-linear smoother: at each node the intercept of a weighted line fit.

    Weights :math:`w_i = \max(0, 1 - |x_i - x_0|/h)`; solves
    :math:`\min_{a,b} \sum_i w_i (y_i - a - b(x_i - x_0))^2` and returns :math:`a` per node.

    Parameters
    ----------
    x, y : numpy.ndarray
        Sample abscissae and values.
    nodes : numpy.ndarray
        Abscissae of the map nodes (units of ``x``).
    half_width : float
        Kernel half-width h (units of ``x``).

    Returns
    -------
    numpy.ndarray
        The smoothed value per node.
    """
    d = x[None, :] - nodes[:, None]
    w = np.clip(1.0 - np.abs(d) / half_width, 0.0, None)
    s0, s1, s2 = w.sum(1), (w * d).sum(1), (w * d * d).sum(1)
    t0, t1 = (w * y).sum(1), (w * d * y).sum(1)
    det = s0 * s2 - s1 * s1
    if np.any(det <= 1e-12 * np.maximum(s0 * s2, 1e-300)):
        raise EstimatorError("quasi-static: a lift has too few samples near a map node; "
                             "use a larger --grid-step")
    return (s2 * t0 - s1 * t1) / det


class BoomTorque:
    """The thesis' sensor set: the mapped load is the measured boom torque, N·m."""

    #: No cylinder: the load is measured as a torque.
    areas = None

    @classmethod
    def fit(cls, estimator) -> "BoomTorque":
        """The load of ``estimator``'s 2-link machine (one clear line for a hydraulic one).

        Parameters
        ----------
        estimator : QuasiStaticEstimator
            The estimator (its name and machine).
        """
        if HYDRAULIC.owns(estimator.machine):
            raise EstimatorError(f"{estimator.name}: the hydraulic machine '{estimator.machine.name}' goes "
                                 "with machine-sensor-set data")
        return cls()

    def of_rows(self, rows) -> np.ndarray:
        """The load of a lift's rows, N·m.

        Parameters
        ----------
        rows : pandas.DataFrame
            Thesis-set samples.
        """
        return rows["boom_torque"].to_numpy(float)

    def bind(self, sensors) -> None:
        """Find the load's signal in the sensor set's order (for :meth:`of_sample`).

        Parameters
        ----------
        sensors : SensorSet
            The sensor set the samples come in.
        """
        self._index = sensors.index("boom_torque")

    def of_sample(self, values: np.ndarray) -> float:
        """The load of one sample, N·m.

        Parameters
        ----------
        values : numpy.ndarray
            The sample in the sensor set's order.
        """
        return float(values[self._index])

    def config(self) -> dict:
        """Nothing to save."""
        return {}


class BoomPistonForce:
    """The machine sensor set: the mapped load is the boom cylinder's piston force
    :math:`p_h A_h - p_r A_r`, N (the boom torque is not measured).

    Parameters
    ----------
    head_area, rod_area : float
        The boom cylinder's head and rod areas, m².
    """

    def __init__(self, head_area: float, rod_area: float) -> None:
        #: Boom cylinder (head, rod) areas, m².
        self.areas = (head_area, rod_area)

    @classmethod
    def fit(cls, estimator) -> "BoomPistonForce":
        """The load of ``estimator``'s hydraulic machine (one clear line for a 2-link one).

        Parameters
        ----------
        estimator : QuasiStaticEstimator
            The estimator (its name and machine).
        """
        if not HYDRAULIC.owns(estimator.machine):
            raise EstimatorError(f"{estimator.name}: data of the machine sensor set need a hydraulic "
                                 f"machine file, not '{estimator.machine.name}' (e.g. --machine "
                                 "cat345c-hydraulic)")
        cylinder = estimator.machine.boom_cylinder
        return cls(float(cylinder.head_area), float(cylinder.rod_area))

    def of_rows(self, rows) -> np.ndarray:
        """The load of a lift's rows, N.

        Parameters
        ----------
        rows : pandas.DataFrame
            Machine-set samples.
        """
        head, rod = self.areas
        return (rows["boom_head_pressure"].to_numpy(float) * head
                - rows["boom_rod_pressure"].to_numpy(float) * rod)

    def bind(self, sensors) -> None:
        """Find the pressures in the sensor set's order (for :meth:`of_sample`).

        Parameters
        ----------
        sensors : SensorSet
            The sensor set the samples come in.
        """
        self._head, self._rod = sensors.indices(("boom_head_pressure", "boom_rod_pressure"))

    def of_sample(self, values: np.ndarray) -> float:
        """The load of one sample, N.

        Parameters
        ----------
        values : numpy.ndarray
            The sample in the sensor set's order.
        """
        return float(values[self._head]) * self.areas[0] - float(values[self._rod]) * self.areas[1]

    def config(self) -> dict:
        """The cylinder areas."""
        return {"boom_areas": list(self.areas)}


def saved_load(config: dict) -> BoomTorque | BoomPistonForce:
    """The mapped load a saved model's state describes (its ``boom_areas``: the piston force).

    Parameters
    ----------
    config : dict
        The saved state.
    """
    areas = config.get("boom_areas")
    return BoomTorque() if areas is None else BoomPistonForce(float(areas[0]), float(areas[1]))


@register
class QuasiStaticEstimator(Estimator):
    """Two characteristic boom-torque maps (empty, rated) and linear interpolation between them.

    Parameters
    ----------
    machine : Machine, str or None
        The machine model the estimator believes in (preset name or file; None: ``cat345c``).
    **options
        Estimator options, see the class attribute ``OPTIONS``.
    """

    name = "quasi-static"
    # SENSOR_SETS: from its traits (estimators/traits.py)
    OPTIONS = {
        "grid_step": Option(float, 2.0, "boom-angle spacing of the maps, degrees"),
        "speed_tolerance": Option(float, 0.05, "a lift's constant-speed part starts and ends where "
                                  "its boom rate is within this relative deviation of the median"),
        "trim": Option(float, 0.5, "seconds dropped at both ends of a lift's constant-speed part"),
        "speed_gate": Option(bool, False, "use only samples at the calibration speed (boom rate within "
                             "--speed-tolerance of it, dipper still), as the patent prescribes"),
        "averaging": Option(str, "cumulative", "report the running mean since the experiment "
                            "started, or each sample's value", ("cumulative", "none")),
    }
    #: The mapped load of each platform, by platform name: picked at fit for the data's platform.
    LOADS = {THESIS.name: BoomTorque, HYDRAULIC.name: BoomPistonForce}

    def __init__(self, machine=None, **options) -> None:
        super().__init__(machine, **options)
        if not self.options["grid_step"] > 0:
            raise EstimatorError(f"{self.name}: option --grid-step must be > 0 degrees")
        if not 0 < self.options["speed_tolerance"] < 1:
            raise EstimatorError(f"{self.name}: option --speed-tolerance must be in (0, 1)")
        if not self.options["trim"] >= 0:
            raise EstimatorError(f"{self.name}: option --trim must be >= 0 seconds")
        self.reference_payloads = (math.nan, math.nan)
        self.calibration_speed = math.nan
        self.boom_nodes = np.zeros(0)
        self.dipper_nodes: list[np.ndarray] = []
        self.maps: list[np.ndarray] = []
        #: The mapped load (:data:`LOADS`): the boom torque until fit on machine-set data.
        self.load: BoomTorque | BoomPistonForce = BoomTorque()
        self._reset()

    @property
    def boom_areas(self) -> tuple[float, float] | None:
        """Boom cylinder (head, rod) areas, m², on the machine sensor set (None: boom torque)."""
        return self.load.areas

    # -- calibration -----------------------------------------------------------------------
    def _lift_part(self, exp_id: int, rows) -> tuple[np.ndarray, np.ndarray, float, float]:
        """(boom angle, boom torque, dipper angle, speed) of a lift's constant-speed part.

        The constant-speed part runs from the first to the last sample whose boom rate is within
        ``speed_tolerance`` of the lift's median rate, shortened by ``trim`` seconds at both ends
        (where the speed ramps still accelerate the arm).
        """
        time = rows["time"].to_numpy(float)
        boom = rows["boom_angle"].to_numpy(float)
        rate = rows["boom_rate"].to_numpy(float)
        dipper = rows["dipper_angle"].to_numpy(float)
        torque = self.load.of_rows(rows)
        finite = (np.isfinite(time) & np.isfinite(boom) & np.isfinite(rate) & np.isfinite(dipper)
                  & np.isfinite(torque))
        time, boom, rate, dipper, torque = (a[finite] for a in (time, boom, rate, dipper, torque))
        if len(boom) < 10:
            raise EstimatorError(f"quasi-static: experiment {exp_id} has too few valid samples")
        speed = float(np.median(rate))
        if abs(speed) < 0.1 * DEG:
            raise EstimatorError(f"quasi-static: experiment {exp_id} is not a lift (the boom does not "
                                 "move); calibrate with lifts, e.g. `excavator-payload simulate "
                                 "--motion lifts`")
        steady = np.abs(rate - speed) <= self.options["speed_tolerance"] * abs(speed)
        idx = np.flatnonzero(steady)
        trim = self.options["trim"]
        use = (time >= time[idx[0]] + trim) & (time <= time[idx[-1]] - trim)
        if (use.sum() < 10 or steady[use].mean() < 0.5 or np.ptp(dipper[use]) > 2 * DEG):
            raise EstimatorError(f"quasi-static: experiment {exp_id} is not a constant-speed lift "
                                 "with the dipper held still")
        return boom[use], torque[use], float(np.mean(dipper[use])), speed

    def _fit(self, dataset: Dataset) -> None:
        self.load = self.LOADS[platform_for(dataset).name].fit(self)
        lifts = [(i, *self._lift_part(i, rows)) for i, rows in dataset.experiments()]
        payloads = dataset.payloads
        if not np.all(np.isfinite(payloads)):
            raise EstimatorError("quasi-static: calibration lifts need known payloads")
        levels = np.unique(np.round(payloads, 3))
        if len(levels) != 2:
            raise EstimatorError(
                f"quasi-static: calibration needs lifts at exactly two reference payloads (empty and "
                f"rated), the data have {len(levels)} payload level(s); make them with "
                "`excavator-payload simulate --motion lifts`")
        speeds = np.array([lift[4] for lift in lifts])
        if np.any(np.sign(speeds) != np.sign(speeds[0])) or np.ptp(np.abs(speeds)) > 0.2 * np.abs(speeds).mean():
            raise EstimatorError("quasi-static: all calibration lifts must run at the same speed "
                                 "in the same direction")
        lo = max(float(lift[1].min()) for lift in lifts)
        hi = min(float(lift[1].max()) for lift in lifts)
        step = self.options["grid_step"] * DEG
        if hi - lo < 2 * step:
            raise EstimatorError("quasi-static: the lifts share less than two grid steps of boom range")
        boom_nodes = lo + step * np.arange(int(math.floor((hi - lo) / step + 1e-9)) + 1)

        maps, dipper_nodes = [], []
        for level in levels:
            mine = sorted([(dipper, local_linear(boom, torque, boom_nodes, step))
                           for (_, boom, torque, dipper, _), payload in zip(lifts, payloads)
                           if round(float(payload), 3) == level], key=lambda item: item[0])
            # Lifts whose dipper angles lie within DIPPER_MERGE of each other form one map line.
            groups: list[list] = []
            for dipper, line in mine:
                if groups and dipper - groups[-1][-1][0] < DIPPER_MERGE:
                    groups[-1].append((dipper, line))
                else:
                    groups.append([(dipper, line)])
            if len(groups) < 2:
                raise EstimatorError(f"quasi-static: the {level:g} kg reference needs lifts at two or "
                                     "more dipper angles")
            dipper_nodes.append(np.array([np.mean([d for d, _ in g]) for g in groups]))
            maps.append(np.array([np.mean([line for _, line in g], axis=0) for g in groups]))
        few = [f"{level:g} kg: {len(nodes)}" for level, nodes in zip(levels, dipper_nodes)
               if len(nodes) < MIN_MAP_LINES]
        if few:
            self.fit_warnings.append(
                f"quasi-static: few calibration dipper angles ({'; '.join(few)}); between and beyond "
                "them the map is a straight-line guess and estimates can be several payloads off. "
                f"Calibrate with lifts at {MIN_MAP_LINES} or more dipper angles per reference payload")
        if not self._maps_separated(maps, dipper_nodes, boom_nodes):
            raise EstimatorError("quasi-static: the rated map is not above (or below) the empty map "
                                 "everywhere, so the maps cannot be interpolated; check the "
                                 "reference payloads")
        self.reference_payloads = (float(levels[0]), float(levels[1]))
        self.calibration_speed = float(np.mean(speeds))
        self.boom_nodes, self.dipper_nodes, self.maps = boom_nodes, dipper_nodes, maps
        self._prepare()

    @staticmethod
    def _maps_separated(maps, dipper_nodes, boom_nodes) -> bool:
        # The torque difference must keep one sign: the interpolation divides by it.
        other = np.array([[np.interp(d, dipper_nodes[1], maps[1][:, j]) for j in range(len(boom_nodes))]
                          for d in dipper_nodes[0]])
        diff = other - maps[0]
        return bool(np.all(diff > 0) or np.all(diff < 0))

    def _prepare(self) -> None:
        """Plain-Python copies for the streaming lookup."""
        self._b0 = float(self.boom_nodes[0])
        self._db = float(self.boom_nodes[1] - self.boom_nodes[0])
        self._nb = len(self.boom_nodes)
        self._dn = [list(map(float, d)) for d in self.dipper_nodes]
        self._maps = [m.tolist() for m in self.maps]
        self._m_lo, self._m_hi = self.reference_payloads
        self._cumulative = self.options["averaging"] == "cumulative"
        self._gate = bool(self.options["speed_gate"])
        self._speed = float(self.calibration_speed)
        self._speed_tol = float(self.options["speed_tolerance"]) * abs(self._speed)
        sensors = self.sensor_set
        self._i_boom, self._i_boom_rate, self._i_dipper, self._i_dipper_rate = sensors.indices(
            ("boom_angle", "boom_rate", "dipper_angle", "dipper_rate"))
        self.load.bind(sensors)

    def _lookup(self, level: int, boom: float, dipper: float) -> float | None:
        """Bilinear interpolation of map ``level`` at (boom, dipper); None outside the map."""
        x = (boom - self._b0) / self._db
        nodes = self._dn[level]
        if not (0.0 <= x <= self._nb - 1) or not (nodes[0] <= dipper <= nodes[-1]):
            return None
        i = min(int(x), self._nb - 2)
        fx = x - i
        j = min(max(bisect.bisect_right(nodes, dipper) - 1, 0), len(nodes) - 2)
        fy = (dipper - nodes[j]) / (nodes[j + 1] - nodes[j])
        row0, row1 = self._maps[level][j], self._maps[level][j + 1]
        a = row0[i] + fx * (row0[i + 1] - row0[i])
        b = row1[i] + fx * (row1[i + 1] - row1[i])
        return a + fy * (b - a)

    def reference_torques(self, boom: float, dipper: float) -> tuple[float, float] | None:
        """(empty, rated) map torques at an arm pose, N·m (None outside the maps).

        Parameters
        ----------
        boom, dipper : float
            Boom and dipper angles, rad.
        """
        lo, hi = self._lookup(0, boom, dipper), self._lookup(1, boom, dipper)
        return None if lo is None or hi is None else (lo, hi)

    # -- streaming -------------------------------------------------------------------------
    #: The map has no noise model: it borrows the gate of its calibration data's physics.
    BORROWS_GATE = True

    def _on_skip(self, time: float, values: np.ndarray) -> None:
        """Nothing before the next sample is judged; see :meth:`_fill_rejected`."""

    def _fill_rejected(self, time: float, values: np.ndarray) -> None:
        """A rejected sample's place in the running mean gets the value interpolated between
        its neighbours (leaving it out would shift a mean that moves through the swing)."""
        self._interpolate_rejected(time, values)

    def _reset(self) -> None:
        self._sum = 0.0
        self._count = 0

    def _step(self, time: float, values: np.ndarray) -> StepResult:
        boom, dipper = float(values[self._i_boom]), float(values[self._i_dipper])
        torque = self.load.of_sample(values)  # machine sensor set: the boom piston force
        if self._gate and (abs(float(values[self._i_boom_rate]) - self._speed) > self._speed_tol
                           or abs(float(values[self._i_dipper_rate])) > self._speed_tol):
            held = self._last_estimate  # not at the calibration speed: keep the last value
            return StepResult(held, Status.NO_DATA if math.isnan(held) else Status.OK)
        refs = self.reference_torques(boom, dipper)
        if refs is None:
            return StepResult(self._last_estimate, Status.OUT_OF_RANGE)
        tau_lo, tau_hi = refs
        m = self._m_lo + (self._m_hi - self._m_lo) * (torque - tau_lo) / (tau_hi - tau_lo)
        if not self._cumulative:
            return StepResult(m, Status.OK)
        self._sum += m
        self._count += 1
        return StepResult(self._sum / self._count, Status.OK)

    # -- persistence -----------------------------------------------------------------------
    def _config(self) -> dict:
        return {"reference_payloads": list(self.reference_payloads),
                "calibration_speed": self.calibration_speed, **self.load.config()}

    def _arrays(self) -> dict[str, np.ndarray]:
        return {"boom_nodes": self.boom_nodes,
                "empty_dipper_nodes": self.dipper_nodes[0], "empty_map": self.maps[0],
                "rated_dipper_nodes": self.dipper_nodes[1], "rated_map": self.maps[1]}

    def _restore(self, config: dict, arrays: Mapping[str, np.ndarray]) -> None:
        refs = config["reference_payloads"]
        self.reference_payloads = (float(refs[0]), float(refs[1]))
        self.calibration_speed = float(config["calibration_speed"])
        self.load = saved_load(config)
        self.boom_nodes = np.asarray(arrays["boom_nodes"], float)
        self.dipper_nodes = [np.asarray(arrays["empty_dipper_nodes"], float),
                             np.asarray(arrays["rated_dipper_nodes"], float)]
        self.maps = [np.asarray(arrays["empty_map"], float), np.asarray(arrays["rated_map"], float)]
        for nodes, grid in zip(self.dipper_nodes, self.maps):
            if grid.shape != (len(nodes), len(self.boom_nodes)) or len(nodes) < 2 or len(self.boom_nodes) < 2:
                raise EstimatorError("saved maps have inconsistent shapes (corrupt model folder)")
        self._prepare()
