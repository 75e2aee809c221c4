"""Measure the C export's sensor health monitor (docs/sensor-health.md): ns per ``ep_step`` with
and without it (``-DEP_HEALTH=0``) on a work-cycle replay, ``sizeof(ep_state)``, code size and
the lines of generated C it adds. Run:
``OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/measure_export_c_health.py``."""

import statistics
import subprocess
import tempfile
from pathlib import Path

from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.c_harness import build, c_compiler
from excavator_payload.runtime.export_c import export_c, template
from excavator_payload.simulation.machine_sim import simulate_machine_dataset


def _lines(paths) -> int:
    return sum(len(Path(p).read_text().splitlines()) for p in paths)


def _state_size(header: Path, folder: Path, flags) -> int:
    """sizeof(ep_state) as the model's object sees it (the harness's own build does not get
    the -D flags)."""
    program = folder / "size.c"
    program.write_text(f'#include <stdio.h>\n#include "{header.resolve()}"\n'
                       'int main(void) { printf("%lu\\n", (unsigned long)sizeof(ep_state)); return 0; }\n')
    subprocess.run([c_compiler(), "-std=c99", *flags, str(program), "-o", str(folder / "size")], check=True)
    return int(subprocess.run([str(folder / "size")], check=True, capture_output=True, text=True).stdout)


def main(repetitions: int = 20, rounds: int = 7) -> None:
    fitting = simulate_machine_dataset(3, seed=3)
    replay = simulate_machine_dataset(3, seed=32, session=2, motion="work-cycle")
    print(f"replay: {len(replay.frame)} samples of clean work cycles, {repetitions} repetitions per timing, "
          f"{rounds} rounds (with / without in turn)")
    models = {"inverse-dynamics": create_estimator("inverse-dynamics", machine="cat345c-hydraulic"),
              "calibrated-momentum": create_estimator("calibrated", machine="cat345c-hydraulic-3pct",
                                                      balance="momentum")}
    for name, est in models.items():
        est.fit(fitting)
        folder = Path(tempfile.mkdtemp())
        paths = export_c(est, folder / "with")
        original = template.health_c
        template.health_c = lambda e: None  # the same export without the monitor's text
        try:
            bare = export_c(est, folder / "without")
        finally:
            template.health_c = original
        print(f"{name}: generated C {_lines(bare)} -> {_lines(paths)} lines (+{_lines(paths) - _lines(bare)})")
        for single in (False, True):
            on = build(paths[1], folder / f"on{single}", single=single)
            off = build(paths[1], folder / f"off{single}", single=single, extra_flags=("-DEP_HEALTH=0",))
            times_on, times_off = [], []
            for _ in range(rounds):
                times_on.append(on.bench(replay, repetitions))
                times_off.append(off.bench(replay, repetitions))
            ratio = statistics.median(a / b for a, b in zip(times_on, times_off))
            print(f"  {'float' if single else 'double'}: ns/step with {statistics.median(times_on):.0f} "
                  f"({min(times_on):.0f}-{max(times_on):.0f}), without {statistics.median(times_off):.0f} "
                  f"({min(times_off):.0f}-{max(times_off):.0f}), ratio {ratio:.2f}; "
                  f"sizeof(ep_state) {_state_size(paths[0], folder, [f'-DEP_SINGLE={int(single)}'])} vs "
                  f"{_state_size(paths[0], folder, [f'-DEP_SINGLE={int(single)}', '-DEP_HEALTH=0'])} B; "
                  f".text {on.text_size()} vs {off.text_size()} B")


if __name__ == "__main__":
    main()
