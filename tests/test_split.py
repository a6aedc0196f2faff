"""Training and validation blocks (mavsid.split): a block cut from a longer record keeps the
inputs before it, so that a model's input filters and delay start where the record had them.

The reference is scipy: the plant and its input lag run over the whole record with
``scipy.signal.lfilter``; a held-out block's free run must be that run's slice."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal

from mavsid.data import Segment
from mavsid.estimators.model import Model
from mavsid.estimators.regressors import InputFilter
from mavsid.split import split_segments
from mavsid.validation import validate

DT = 0.01
A_D, B_D = 0.96, 0.8  # (a rate plant: pole 4.1 1/s)
LAG = InputFilter(5.3, order=1, source="input lag 30 ms")
DELAY = 2  # samples


def chirp_record(seconds: float = 16.0) -> Segment:
    """A SYSTEMID-like chirp (0.5 -> 12 Hz) through a 30-ms lag, 2 samples of delay and the
    plant, all by scipy over the whole record; no noise."""
    t = np.arange(round(seconds / DT)) * DT
    f0, f1 = 0.5, 12.0
    u = 0.2 * signal.chirp(t, f0, t[-1], f1, method="logarithmic")
    b, a = signal.butter(1, LAG.cutoff_hz, fs=1.0 / DT)
    lagged = signal.lfilter(b, a, u, zi=signal.lfilter_zi(b, a) * u[0])[0]
    delayed = np.concatenate([np.full(DELAY, lagged[0]), lagged[:-DELAY]])
    x = np.zeros(t.size)
    x[1:] = signal.lfilter([B_D], [1.0, -A_D], delayed[:-1])
    return Segment(t, x[:, None], u[:, None], ("p",), ("u_roll",), DT, "roll", "sysid")


def truth() -> Model:
    return Model(("p",), ("u_roll",), ("p", "u_roll"), np.array([[A_D], [B_D]]), DT,
                 delay=DELAY, filters=(LAG,))


def test_a_held_out_blocks_free_run_is_the_whole_records_run() -> None:
    """Four interleaved blocks of a chirp: each held-out block's free run (from its measured
    first state) is the true plant's run over the whole record, to rounding. Started cold
    at its first input, the lag's transient was integrated by the slow plant: the fast
    block's free run fell to 25 % here (to 6 % on a simulated heavy quad's chirp), the two
    blocks' to 90 %."""
    record = chirp_record()
    train, held = split_segments([record])
    assert len(train) == len(held) == 2
    model = truth()
    for block in held:
        i0 = round(block.start_s / DT)
        before = block.inputs_before
        assert before is not None and len(before) == min(i0, 200)
        np.testing.assert_allclose(before, record.inputs[i0 - len(before):i0])
        np.testing.assert_allclose(model.simulate(block), record.states[i0:i0 + len(block)],
                                   atol=1e-9)
    val = validate(model, held)
    assert val.fit_free_run[0] > 99.999
    cold = validate(model, [dataclasses.replace(b, inputs_before=None) for b in held])
    assert cold.fit_free_run[0] < 99.0  # (what the history is for)


def test_the_first_block_and_a_cut_of_a_cut_keep_the_history_they_have() -> None:
    """The record's first block has none (the filters start in steady state, as before); a
    block cut again (an estimator's sub-block) carries its own history on, up to 2 s."""
    record = chirp_record()
    train, _ = split_segments([record])
    assert train[0].inputs_before is None
    late = record.cut(1000, 1400)
    sub = late.cut(50, 100)
    assert sub.inputs_before is not None and len(sub.inputs_before) == 200
    np.testing.assert_allclose(sub.inputs_before, record.inputs[850:1050])
    np.testing.assert_allclose(truth().simulate(sub), record.states[1050:1100], atol=1e-9)

