"""The run's verdicts on metrics.json (graphtrack.io.run_output): the lock that does not
hold, judged on hand-made metrics."""
import pytest

from graphtrack.errors import InputError
from graphtrack.io.run_output import lock_problem, lock_refused, require_lock


def _metrics(adopted, frames, stereo=None, batch=False):
    report = {"searches": adopted, "adopted": adopted}
    m = {"estimator_report": {"iterations": 3, "online": report} if batch else report,
         "frames_with_detections": frames}
    if stereo is not None:
        m["stereo"] = stereo
    return m


@pytest.mark.parametrize("adopted, frames, warned, refused", [
    (2, 2, False, False),      # a start-up and one re-acquisition: never reported
    (3, 30, False, False),     # a tenth of the frames: not more than LOCK_WARN
    (3, 29, True, False),
    (3, 6, True, True),        # half: nothing tracked from frame to frame
    (3, 7, True, False),
    (60, 60, True, True),
])
def test_lock_thresholds(adopted, frames, warned, refused):
    m = _metrics(adopted, frames)
    assert (lock_problem(m, "SEQ") is not None) == warned
    assert lock_refused(m) == refused


def test_lock_message_names_the_recording_and_stereo_order():
    mono = lock_problem(_metrics(6, 12), "SEQ")
    assert mono.startswith("SEQ: the estimator started over from a global search 6 times in 12 frames")
    assert "--mono" not in mono
    assert "which images are the left ones" in lock_problem(_metrics(6, 12, stereo=True), "SEQ")
    with pytest.raises(InputError, match="nothing was tracked from frame to frame: SEQ"):
        require_lock(_metrics(6, 12), "SEQ")


def test_batch_judged_by_its_online_smoother_and_no_search_never():
    assert lock_refused(_metrics(6, 12, batch=True))
    assert not lock_refused({"estimator_report": {}, "frames_with_detections": 12})
    assert lock_problem({"estimator_report": {}}, "SEQ") is None
    require_lock({}, "SEQ")
