"""The interface of a platform: everything that differs between the thesis' arm and the machine.

A platform is one world the package knows: the thesis' 2-link arm with its joint-torque sensors
(:mod:`.thesis`) or the hydraulic machine with IMUs and cylinder pressures (:mod:`.hydraulic`).
It owns its sensor set (a :class:`~excavator_payload.data.schema.SensorSet`, defined in
:mod:`excavator_payload.data.schema`), how its machine files are loaded, its sensor-noise
presets, the motions it can simulate (one table, :attr:`Platform.motions`), the plausibility
rules its data must pass and the samples an evaluation discards by default. Code that used to
compare sensor-set names or machine kinds asks :func:`~excavator_payload.platforms.platform_for`
once and then the platform.

Adding a machine family: a new module with a :class:`Platform` subclass, listed in
:data:`excavator_payload.platforms.registry.PLATFORMS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

from excavator_payload.data.schema import SensorSet
from excavator_payload.errors import MachineError


# -- the motion table's entries ----------------------------------------------------------------
def nmpc_chunk_size(n_experiments: int) -> int:
    """Experiments per checkpointed chunk of NMPC runs: small enough for a smooth progress bar
    and little lost work on interruption, large enough to keep the per-chunk overhead small.

    Parameters
    ----------
    n_experiments : int
        Experiments of the whole run.
    """
    return int(min(25, max(1, math.ceil(n_experiments / 40))))


def cheap_chunk_size(n_experiments: int) -> int:
    """Motions with computed torques take ~1 ms per experiment: big chunks (small jobs: one).

    Parameters
    ----------
    n_experiments : int
        Experiments of the whole run.
    """
    return int(min(5000, max(1, n_experiments)))


def machine_chunk_size(n_experiments: int) -> int:
    """Hydraulic motions take ~0.05 s each: ≈ 40 chunks of 1–50 experiments.

    Parameters
    ----------
    n_experiments : int
        Experiments of the whole run.
    """
    return int(min(50, max(1, math.ceil(n_experiments / 40))))


@dataclass(frozen=True)
class Motion:
    """A motion family: how one experiment is simulated and how a run is cut into chunks.

    Parameters
    ----------
    experiment : str
        ``"module:function"`` of ``f(spec, experiment) -> (rows DataFrame, metadata dict)``,
        imported lazily in the worker (so the entry must be in a platform's table, not
        registered at run time in the client: remote workers would not see it).
    chunk_size : callable
        Experiments per chunk for a run of ``n`` experiments.
    skip_on : tuple of str
        ``"module:ExceptionClass"`` names: such an error skips the experiment (recorded with its
        reason) instead of stopping the run.
    needs_first_zero : bool
        The run's experiments depend on each other's numbering from 0 (the lifts).
    description : str
        For ``--help``.
    """

    experiment: str
    chunk_size: Callable[[int], int]
    skip_on: tuple[str, ...] = ()
    needs_first_zero: bool = False
    description: str = ""


#: The errors that skip one experiment of a run instead of stopping it.
SIMULATION_FAILURES = ("builtins:RuntimeError", "builtins:ValueError", "builtins:FloatingPointError")


class Platform:
    """One world: sensor set, machine loader, noise presets, motions, plausibility, discard.

    Subclasses set the class attributes below and implement the methods that raise
    :class:`NotImplementedError`.

    Attributes
    ----------
    name : str
        ``"thesis"`` or ``"hydraulic"``.
    label : str
        A phrase for messages (``"a hydraulic machine"``).
    sensors : SensorSet
        The sensor set its data carry.
    motions : dict of str to Motion
        The motions it can simulate, the first the default.
    noise_presets : dict
        Its sensor-noise presets by name.
    default_noise : str
        The noise preset used unless told.
    kind : str
        The machine kind, as ``excavator-payload machines`` lists it.
    """

    name: str = ""
    label: str = ""
    kind: str = ""
    sensors: SensorSet
    motions: dict[str, Motion] = {}
    noise_presets: dict[str, Any] = {}
    default_noise: str = ""

    @property
    def default_motion(self) -> str:
        """The motion simulated unless told: the first of :attr:`motions`."""
        return next(iter(self.motions))

    # -- sensors -----------------------------------------------------------------------------
    @property
    def sample_rate(self) -> float:
        """Sample rate of its sensor set, Hz."""
        return self.sensors.sample_rate

    def default_discard(self) -> int:
        """Samples not judged at the start of every experiment unless told (evaluation)."""
        raise NotImplementedError

    def carries(self, thing: Any) -> bool:
        """Whether ``thing`` (a dataset, a sensor set, anything with a ``sensor_set``) holds this
        platform's sensor set.

        Parameters
        ----------
        thing : Dataset, SensorSet, str or object with a ``sensor_set``
            What to ask about (a string: a sensor set's name, as saved files hold it).
        """
        if isinstance(thing, str):
            return thing == self.sensors.name
        sensors = thing if isinstance(thing, SensorSet) else getattr(thing, "sensor_set", None)
        return sensors is not None and sensors.name == self.sensors.name

    def runs(self, estimator: Any) -> bool:
        """Whether ``estimator`` (a class or an instance) declares this platform's sensor set
        among those it runs on (its ``SENSOR_SETS``, from its traits).

        Parameters
        ----------
        estimator : Estimator class or instance
            What to ask about.
        """
        return self.sensors.name in getattr(estimator, "SENSOR_SETS", ())

    # -- noise -------------------------------------------------------------------------------
    def noise(self, preset: Any = None) -> Any:
        """The noise preset called ``preset`` (an object is returned as it is; ``None``: the
        platform's default).

        Parameters
        ----------
        preset : str or preset object, optional
            Name (``thesis``, ``none``, ``field`` …) or an already resolved preset.
        """
        raise NotImplementedError

    # -- machines ----------------------------------------------------------------------------
    def owns(self, machine: Any) -> bool:
        """Whether ``machine`` (an object) is a machine of this platform.

        Parameters
        ----------
        machine : object
            A machine object.
        """
        raise NotImplementedError

    def load_machine(self, machine: Any) -> Any:
        """The machine ``machine`` (preset name, TOML file or object), loaded once; refused when
        it is of another platform.

        Parameters
        ----------
        machine : str, Path or machine object
            What to load.

        Raises
        ------
        MachineError
            Unknown, bad, or of another platform.
        """
        from excavator_payload.model.machine import load_machine

        loaded = load_machine(machine)
        if not self.owns(loaded):
            raise MachineError(f"machine '{getattr(loaded, 'name', machine)}' is not {self.label}")
        return loaded

    # -- motions -----------------------------------------------------------------------------
    def motion(self, name: str) -> Motion:
        """The motion family ``name`` of :attr:`motions`.

        Parameters
        ----------
        name : str
            A key of :attr:`motions`.

        Raises
        ------
        excavator_payload.errors.ExcavatorPayloadError
            One line listing the platform's motions.
        """
        from excavator_payload.errors import ExcavatorPayloadError

        try:
            return self.motions[name]
        except KeyError:
            raise ExcavatorPayloadError(f"unknown motion '{name}' for {self.label}: choose one of "
                                        f"{', '.join(self.motions)}") from None

    def simulation_settings(self, machine: Any, motion: str | None, noise: Any, *, session: int = 0,
                            trajectory: Any = None, payload: float | None = None,
                            smooth: float | None = None, allow_overspeed: bool = False,
                            truck_target: float | None = None,
                            frozen_noise_seed: int | None = None) -> tuple[str, Any, dict]:
        """Check a simulation's platform-specific settings: (motion, noise preset, options).

        The motion defaults to the platform's; options the platform does not take are refused
        with one line. Reading a trajectory file is left to the caller (the simulator).

        Parameters
        ----------
        machine : machine object
            The machine simulated (already loaded).
        motion : str or None
            Motion family asked for (``None``: the default).
        noise : str, preset or None
            Noise preset asked for (``None``: the default).
        session : int
            Working session (hydraulic machine).
        trajectory : object or None
            A trajectory to replay (hydraulic machine).
        payload : float or None
            Fixed payload, kg (hydraulic machine).
        smooth : float or None
            Trajectory smoothing, s (hydraulic machine).
        allow_overspeed : bool
            Replay a trajectory faster than the pumps give (hydraulic machine).
        truck_target : float or None
            Load each truck of a shift aims at, kg (hydraulic machine).
        frozen_noise_seed : int or None
            The same noise in every experiment (thesis).
        """
        raise NotImplementedError

    def run_meta(self, spec: Any) -> dict:
        """File metadata a simulated run of this platform adds (none by default).

        Parameters
        ----------
        spec : RunSpec
            The run.
        """
        return {}

    # -- plausibility ------------------------------------------------------------------------
    def check_plausible(self, frame: Any, machine: Any, source: str) -> None:
        """The platform's plausibility rules beyond the sensor set's units and ranges (none by
        default).

        Parameters
        ----------
        frame : pandas.DataFrame
            ``experiment``, ``time`` and the sensor set's signals.
        machine : machine object or None
            The machine believed to have made the data.
        source : str
            Named in the error message.

        Raises
        ------
        excavator_payload.errors.DatasetError
            One line naming the experiment and the columns.
        """

    def __repr__(self) -> str:
        return f"<platform {self.name}: {self.sensors.name} sensors at {self.sample_rate:g} Hz>"
