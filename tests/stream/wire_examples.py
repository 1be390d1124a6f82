"""One valid message of each wire type, and the refusal reason of a payload: shared by the
round-trip, rejection, robustness and fuzz tests, which build their cases from these."""

from __future__ import annotations

import pytest

from stream.compensation import CompensationRequest
from wire import (
    Batch,
    DataPoint,
    Diagnostics,
    JointSample,
    Metrics,
    ModelHeader,
    RejectedMessageError,
    TemperatureSample,
    TrackerSample,
    decode,
)

JOINT = JointSample(seq=1, t=10.0, q=(0.1,) * 6, qs=(0.1,) * 6)
TRACKER = TrackerSample(seq=2, t=10.5, xyz=(1.0, 0.0, 0.5), quat=(0.0, 0.0, 0.0, 1.0))
TEMPERATURE = TemperatureSample(seq=3, t=11.0, names=("ambient", "j1"), values=(21.0, 25.0))
POINT = DataPoint(
    seq=3, t=12.5, q=(0.1,) * 6, xyz=(1.0, 0.2, 0.5), quat=(0.0, 0.0, 0.0, 1.0), qs=(0.1,) * 6,
    temperature_names=("ambient",), temperatures=(21.0,),
)  # fmt: skip
BATCH = Batch(seq=4, points=(POINT, POINT), epoch=1_700_000_000_000, first=8)
HEADER = ModelHeader(model_version=3, robot="fanuc_m900ib700", n_seen=200, t=12.0)
METRICS = Metrics(
    model_version=3, n_seen=200, memory_size=50, train_time_s=0.2, test_mean_mm=0.3,
    test_max_mm=1.0, batch_mean_mm=0.4, aleatoric_mm=0.1, epistemic_mm=0.1,
    epistemic_p90_mm=0.2, memory_age=(10, 5), t=13.0,
)  # fmt: skip
DIAGNOSTICS = Diagnostics(stage="window", accepted=10, dropped={"late": 2}, t=14.0)
#: The JSON messages that round-trip through ``encode``/``decode``, in stream order.
SAMPLES = (JOINT, TRACKER, TEMPERATURE, POINT, BATCH)
VALID = (
    *SAMPLES,
    HEADER,
    METRICS,
    DIAGNOSTICS,
    CompensationRequest(q=(0.1,) * 6, temperatures={"ambient": 21.0}),
    CompensationRequest(q=(0.1,) * 6, target_xyz=(1.5, 0.0, 1.0), target_quat=(0.0, 0.0, 0.0, 1.0)),
)


def decode_refusal(payload: bytes | str, cls: type) -> str:
    """The reason ``decode`` refuses ``payload`` as a ``cls`` with (the test fails if it
    decodes)."""
    with pytest.raises(RejectedMessageError) as exc:
        decode(payload, cls)
    return exc.value.reason
