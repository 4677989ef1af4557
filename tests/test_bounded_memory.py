"""The simulated plant keeps only what its sensors need: memory flat over long runs."""

from __future__ import annotations

import numpy as np
import pytest

from rig.model.action import ActionModel


def test_stepper_without_history_gives_the_same_chunks_and_keeps_none() -> None:
    model = ActionModel(effects=[], output_rate=2000.0)
    kept, flat = model.stepper(), model.stepper(keep_history=False)
    chunks = {}
    for name, st in (("kept", kept), ("flat", flat)):  # one after the other (shared workspace)
        chunks[name] = [st.advance(j * 2e-3, 0.5 * (j - 1), 0.5 * j)  # 80 ms ramp to 20 N
                        for j in range(1, 41)]
    for a, b in zip(chunks["kept"], chunks["flat"], strict=True):
        np.testing.assert_array_equal(a.states, b.states)
        np.testing.assert_array_equal(a.time, b.time)
    assert len(kept._times) == 41 and flat._times == [] and flat._states == []
    assert kept.result().time.size == 161
    with pytest.raises(RuntimeError, match="keeps no history"):
        flat.result()


def test_the_simulated_rig_steps_without_history() -> None:
    from rig import config
    from rig.sim_backend.rig import SimRig

    cfg = config.from_mapping({"backend": "sim", "sim": {"effects": []},
                               "channels": {"strain_gauge": {"enabled": False}}})
    rig = SimRig(cfg)
    for _ in range(50):
        rig.cycle(1.0)
    assert rig.stepper.keep_history is False and rig.stepper._times == []
