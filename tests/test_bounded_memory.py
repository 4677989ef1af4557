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
    from rig.inputs import config
    from rig.sim_backend.simrig import SimRig

    cfg = config.from_mapping({"backend": "sim", "sim": {"effects": []},
                               "channels": {"strain_gauge": {"enabled": False}}})
    rig = SimRig(cfg)
    for _ in range(50):
        rig.cycle(1.0)
    assert rig.stepper.keep_history is False and rig.stepper._times == []


class _Q:
    def __init__(self) -> None:
        self.items: list = []

    def put(self, item) -> None:
        self.items.append(item)


def test_loop_records_keep_only_the_last_rows_once_sent() -> None:
    from rig.loop.recovery import LoopRecords

    rec = LoopRecords(trials=2, total=300, keep=40)
    q = _Q()
    for i in range(250):
        k = 0 if i < 150 else 1
        rec.add([i * 2e-3, i, 1.0, 1.0, 1.0, 0.1, 0.0, 0.5, 1e-4 * (i % 7), float(i == 3), k])
        if rec.unsent() >= 50:
            rec.send(q)
    assert len(rec.rows) <= 50 + 40  # never the whole run
    rec.send(q)
    sent = {0: [], 1: []}
    for _, k, data in q.items:
        sent[k].append(data["tick"])
    assert np.array_equal(np.concatenate(sent[0]), np.arange(150))  # every row sent once
    assert np.array_equal(np.concatenate(sent[1]), np.arange(150, 250))
    first, part = rec.trial_rows(1)  # the kept rows of trial 1 and where they start in it
    assert part.shape[0] == 40 and first == 60 and part[0, 1] == 210
    assert rec.n == 250 and rec.missed[:rec.n].sum() == 1
    assert rec.lateness[:rec.n].max() == pytest.approx(6e-4)
