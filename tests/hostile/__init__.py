"""The hostile and careless user's cases of ``tests/test_hostile_cli.py``, in rooms by what they
feed the command line: :mod:`.harness` (the good inputs, a case, running one), :mod:`.cases_files`
(datasets, trajectories, model folders, machine files), :mod:`.cases_use` (outputs, markup,
arguments, estimates files, CAN logs, what must work). ``benchmarks/hostile_summary.py`` runs the
same cases."""

from __future__ import annotations

from .cases_files import (dataset_cases, hydraulic_machine_cases, machine_cases, machine_dataset_cases,
                          model_cases, trajectory_cases)
from .cases_use import argument_cases, can_cases, estimates_cases, good_cases, markup_cases, output_cases
from .harness import Case

ALL_CASES: list[Case] = (dataset_cases() + machine_dataset_cases() + trajectory_cases() + model_cases() + machine_cases()
                         + hydraulic_machine_cases() + output_cases()
                         + markup_cases() + argument_cases() + estimates_cases() + can_cases() + good_cases())
