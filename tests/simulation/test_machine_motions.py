

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


def test_operator_motions_trimmed_far_out_of_range_are_brought_back():
    """An `operator` motion's trims (±6° each, all along the motion) can drift a joint far past
    its range; 8 halvings of the latest step did not undo that and the motion was returned
    outside (bucket −145° against a range ending at −126°: 727 clean samples `out_of_range`
    in the false-alarm benchmark). Planned motions of many draws now stay inside the ranges."""
    import numpy as np

    from excavator_payload.model.hydraulic import HydraulicArmModel
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_motions import operator_motion

    machine = load_machine("cat345c-hydraulic")
    arm = HydraulicArmModel(machine)
    ranges = machine.angle_ranges
    worst = 0.0
    for k in range(120):
        motion = operator_motion(np.random.default_rng([k, 77]), arm)
        q, _, _ = motion.sample(np.linspace(0, motion.duration, 400))
        worst = max(worst, float(np.max(q[:, :3] - ranges[:, 1])), float(np.max(ranges[:, 0] - q[:, :3])))
    assert worst <= 1e-9, f"a planned operator motion leaves its range by {np.degrees(worst):.2f}°"


def test_reach_motions_cover_the_ranges_swings_leave_and_stay_inside():
    """`reach` calibration motions: every joint inside its range, within the pumps' speed (each
    step no shorter than the hydraulics allow), and together they visit far more of the dipper's
    and bucket's ranges than swings do (the stretches swings never reach)."""
    import numpy as np

    from excavator_payload.model.hydraulic import HydraulicArmModel
    from excavator_payload.model.machine import load_machine
    from excavator_payload.simulation.machine_motions import reach_motion, shortest_duration, swing_motion

    machine = load_machine("cat345c-hydraulic")
    arm = HydraulicArmModel(machine)
    ranges = machine.angle_ranges[:3]

    def visited(make):
        q_all = []
        for k in range(10):
            motion = make(np.random.default_rng([k, 5]), arm)
            q, _, _ = motion.sample(np.linspace(0, motion.duration, 400))
            assert np.all(q[:, :3] <= ranges[:, 1] + 1e-9) and np.all(q[:, :3] >= ranges[:, 0] - 1e-9)
            q_all.append(q[:, :3])
            if make is reach_motion:
                assert all(st.duration >= 0.99 * shortest_duration(arm, st.joint, 0.0, st.delta) or st.joint < 3
                           for st in motion.steps)
        q = np.concatenate(q_all)
        return (q.max(axis=0) - q.min(axis=0)) / (ranges[:, 1] - ranges[:, 0])

    reach, swings = visited(reach_motion), visited(swing_motion)
    assert np.all(reach[1:] > 0.8) and np.all(reach[1:] > swings[1:] + 0.2), (reach, swings)


def test_the_calibration_mix_is_swings_with_three_reach_motions_in_ten():
    """`--motion calibration`: experiments 2, 5 and 8 of every ten are `reach` motions, the rest
    swings, each experiment the same as the family's own with the same seed and number."""
    import numpy as np

    from excavator_payload.simulation.generate import simulate_dataset

    common = dict(seed=3, machine="cat345c-hydraulic", session=1, workers=1, progress=False)
    mix = simulate_dataset(4, motion="calibration", first_experiment=4, **common)
    kinds = {k: m["calibration_motion"] for k, m in mix.experiment_meta.items()}
    assert kinds == {4: "swing", 5: "reach", 6: "swing", 7: "swing"}
    reach = simulate_dataset(1, motion="reach", first_experiment=5, **common)
    swing = simulate_dataset(1, motion="swing", first_experiment=6, **common)
    for own in (reach, swing):
        k = int(own.experiment_ids[0])
        got = mix.frame[mix.frame["experiment"] == k].reset_index(drop=True)
        np.testing.assert_array_equal(got["boom_angle"].to_numpy(), own.frame["boom_angle"].to_numpy())
