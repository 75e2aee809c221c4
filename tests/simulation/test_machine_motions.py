

def test_work_cycles_stay_within_the_stops():
    """The clip halves the step that carries a joint out of its range (not the joint's last
    step): true angles of work cycles and slopes stay within the machine's ranges."""
    import numpy as np

    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.generate import simulate_dataset

    ranges = load_machine("cat345c-hydraulic").angle_ranges
    # experiments whose bucket left its range before (by 0.019 and 0.003 rad)
    for motion, first in (("work-cycle", 39), ("slopes", 34)):
        f = simulate_dataset(1, seed=5, machine="cat345c-hydraulic", motion=motion, with_truth=True,
                             workers=1, progress=False, first_experiment=first).frame
        for j, c in enumerate(("boom_angle", "dipper_angle", "bucket_angle")):
            assert ranges[j, 0] <= f["true_" + c].min() and f["true_" + c].max() <= ranges[j, 1]
