"""Random experiments as the thesis draws them (§5.3, appendix A.2), reproducible from a seed.

Each experiment gets its own :class:`numpy.random.SeedSequence` from ``(base_seed,
experiment)``, so its data do not depend on how many workers run or in which order.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

DEG = np.pi / 180.0

START_BOOM = (-30 * DEG, 10 * DEG)
START_DIPPER = (-110 * DEG, -70 * DEG)
TARGET_BOOM = (30 * DEG, 50 * DEG)
TARGET_DIPPER = (-55 * DEG, -35 * DEG)


@dataclass(frozen=True)
class Scenario:
    """One experiment: start at rest at ``start_pose``, reach ``target_pose`` at rest.

    Parameters
    ----------
    experiment : int
        Experiment number.
    seed : int
        Base seed of the run the experiment was drawn from.
    payload : float
        Payload mass, kg.
    start_pose : tuple of float
        Start (boom, dipper) angles, rad.
    target_pose : tuple of float
        Target (boom, dipper) angles, rad.
    """

    experiment: int
    seed: int
    payload: float  # kg
    start_pose: tuple[float, float]  # rad (boom, dipper)
    target_pose: tuple[float, float]  # rad

    def to_dict(self) -> dict:
        """The scenario as a JSON-able dict (poses as lists)."""
        d = asdict(self)
        d["start_pose"] = list(self.start_pose)
        d["target_pose"] = list(self.target_pose)
        return d


def experiment_rngs(base_seed: int, experiment: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent generators for the scenario and for the sensor noise of one experiment.

    Parameters
    ----------
    base_seed : int
        Base seed of the run.
    experiment : int
        Experiment number; with ``base_seed`` it seeds the experiment's own
        :class:`numpy.random.SeedSequence`.

    Returns
    -------
    scenario_rng, noise_rng : numpy.random.Generator
        Generator of the scenario draws and generator of the sensor noise.
    """
    ss = np.random.SeedSequence([int(base_seed), int(experiment)])
    scenario_ss, noise_ss = ss.spawn(2)
    return np.random.default_rng(scenario_ss), np.random.default_rng(noise_ss)


def sample_scenario(base_seed: int, experiment: int, max_payload: float = 5000.0) -> Scenario:
    """Draw start pose, target pose and payload uniformly in the thesis' ranges.

    Parameters
    ----------
    base_seed : int
        Base seed of the run.
    experiment : int
        Experiment number (draws from the scenario stream of ``(base_seed, experiment)``).
    max_payload : float
        Upper end of the uniform payload range, kg.

    Returns
    -------
    Scenario
        The drawn experiment.
    """
    rng, _ = experiment_rngs(base_seed, experiment)
    start = (rng.uniform(*START_BOOM), rng.uniform(*START_DIPPER))
    target = (rng.uniform(*TARGET_BOOM), rng.uniform(*TARGET_DIPPER))
    payload = rng.uniform(0.0, max_payload)
    return Scenario(int(experiment), int(base_seed), float(payload),
                    (float(start[0]), float(start[1])), (float(target[0]), float(target[1])))
