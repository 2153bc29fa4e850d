"""The run's verdicts on metrics.json (graphtrack.io.run_output): the lock that does not
hold and the estimate the images did not confirm, judged on hand-made metrics."""
import pytest

from graphtrack.errors import InputError
from graphtrack.io.run_output import lock_problem, lock_refused, require_lock, unexplained_problem


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


@pytest.mark.parametrize("judged, explained, warned", [
    (20, 2, True),             # under 15 %
    (20, 3, False),            # 15 %: not under EXPLAINED_WARN
    (9, 0, False),             # too few frames judged to say
    (10, 0, True),
    (0, 0, False),
])
def test_unexplained_thresholds(judged, explained, warned):
    report = {"adopted": 1, "frames_judged": judged, "frames_explained": explained}
    for m in ({"estimator_report": report}, {"estimator_report": {"iterations": 3, "online": report}}):
        problem = unexplained_problem(m, "SEQ")
        assert (problem is not None) == warned
        if warned:
            assert problem.startswith(f"SEQ: the estimate explained the detections on {explained} of the "
                                      f"{judged} frames")
            assert "--handeye-sigma" in problem


def test_unexplained_never_without_the_counts():
    assert unexplained_problem({}, "SEQ") is None
    assert unexplained_problem({"estimator_report": {}}, "SEQ") is None                 # kinematics
    assert unexplained_problem({"estimator_report": {"adopted": 1}}, "SEQ") is None     # --no-search
    assert unexplained_problem({"estimator_report": "odd"}, "SEQ") is None


def test_a_study_folder_and_a_run_folder_are_not_mixed(tmp_path):
    """compare/demo into a track or detect run's folder, or track/detect into a study's, is
    refused naming what is there (they mixed table.md and runs/ with trajectory.csv)."""
    from graphtrack.io.run_output import prepare_run_dir, refuse_other_runs

    run = tmp_path / "run"
    run.mkdir()
    (run / "trajectory.csv").write_text("frame\n")
    (run / "detections.csv").write_text("frame\n")
    with pytest.raises(InputError, match=r"run: holds another command's run \(trajectory.csv, detections.csv\); "
                                         "a study folder is its own"):
        refuse_other_runs(run, "study")
    refuse_other_runs(tmp_path / "new", "study")            # a new folder, or one with other files: fine
    study = tmp_path / "study"
    study.mkdir()
    (study / "study.json").write_text("{}")
    refuse_other_runs(study, "study")
    for overwrite in (False, True):
        with pytest.raises(InputError, match=r"study: holds a study \(study.json"):
            prepare_run_dir(study, overwrite)
    assert (study / "study.json").is_file()


def test_an_interrupt_waits_until_both_writes_are_done():
    """Ctrl-C between a frame's trajectory row and its video frame: raised after both, so an
    interrupted run's video has the frames trajectory.csv has rows for."""
    import os
    import signal

    from graphtrack.io.run_output import deferred_interrupts

    done = []
    # Python's own Ctrl-C handler (a process started in the background inherits SIGINT ignored)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            with deferred_interrupts():
                os.kill(os.getpid(), signal.SIGINT)
                done.append("row")
                done.append("video")
        assert done == ["row", "video"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler   # restored
        with deferred_interrupts():                       # nothing pending: nothing raised
            done.append("next")
        signal.signal(signal.SIGINT, signal.SIG_IGN)      # an ignored Ctrl-C stays ignored
        with deferred_interrupts():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("ignored")
    finally:
        signal.signal(signal.SIGINT, before)
    assert done[-2:] == ["next", "ignored"]
