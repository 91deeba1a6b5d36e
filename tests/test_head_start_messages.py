"""The head start's side of ``rackstress run`` (render/prepare.py): the parent's one-byte
messages over a real pipe, and the pace from which it judges the run's time left."""
import os

from rackstress.render.prepare import _Told
from rackstress.stress.post import Head


def test_follow_does_not_cut_the_loading_short_but_the_end_does():
    r, w = os.pipe()
    try:
        told = _Told(r)
        assert not told.is_set() and not told.urgent()
        os.write(w, b"F")                 # with the first steps: keep loading, then follow
        assert told.is_set() and not told.urgent()
        os.write(w, b"E")                 # the last step is done: stop what is not needed
        assert told.urgent()
        assert told.read() == b"F" and told.read() == b"E" and not told.is_set()
        os.write(w, b"G")
        assert told.is_set() and told.read() == b"G"
        os.close(w)
        w = None
        assert told.urgent() and told.read() == b""       # the parent is gone
    finally:
        os.close(r)
        if w is not None:
            os.close(w)


def test_time_left_from_the_pace_of_the_frames():
    head = Head()
    head.frames = 101
    assert head.seconds_left(now=0.0) == float("inf")          # no pace yet
    head.saw(1, now=10.0)
    assert head.seconds_left(now=10.0) == float("inf")
    head.saw(21, now=10.5)               # 20 frames in 0.5 s: 0.025 s a frame, 80 to come
    assert abs(head.seconds_left(now=10.5) - 2.0) < 1e-12
    assert abs(head.seconds_left(now=11.0) - 1.5) < 1e-12     # time passed since
    head.saw(101, now=12.5)
    assert head.seconds_left(now=12.6) == 0.0
