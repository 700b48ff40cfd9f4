"""The progress reporter of ``areasearch eval`` and ``train`` (:mod:`areasearch.progress`): a
self-overwriting line on a terminal, plain lines at most every interval (and one at the end) elsewhere."""

from __future__ import annotations

import io

from areasearch.progress import Progress, duration


class FakeStream(io.StringIO):
    def __init__(self, terminal: bool) -> None:
        super().__init__()
        self.terminal = terminal

    def isatty(self) -> bool:
        return self.terminal


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _progress(terminal: bool, total: int = 10, **kwargs: object) -> tuple[Progress, FakeStream, FakeClock]:
    stream, clock = FakeStream(terminal), FakeClock()
    return Progress("eval", total, "episodes", stream, clock=clock, **kwargs), stream, clock  # type: ignore[arg-type]


def test_off_a_terminal_a_plain_line_at_most_every_interval_and_one_at_the_end() -> None:
    bar, stream, clock = _progress(False, interval_s=10.0)
    assert stream.getvalue() == ""  # nothing at the start
    for t in (1, 4, 9.5):
        clock.now = 100 + t
        bar.advance()
    assert stream.getvalue() == ""  # less than 10 s since the start
    clock.now = 110.0
    bar.advance()  # 4 done, 10 s: due
    clock.now = 115.0
    bar.advance()
    clock.now = 119.0
    bar.advance()  # only 9 s after the last line
    clock.now = 121.0
    bar.update(8)  # 11 s after it: due
    clock.now = 122.0
    bar.update(10)
    bar.close()
    bar.close()  # a second close adds nothing
    text = stream.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert text.endswith("\n") and len(lines) == 3, text
    assert lines[0].startswith("eval: 4/10 episodes ") and "elapsed 0m10s" in lines[0] and "(40 %)" in lines[0]
    assert lines[1].startswith("eval: 8/10 episodes ")
    assert lines[2].startswith("eval: 10/10 episodes ") and "ETA 0m00s" in lines[2] and "(100 %)" in lines[2]
    assert "0.45 episodes/s" in lines[2]  # 10 episodes in 22 s


def test_off_a_terminal_the_end_is_not_reported_twice() -> None:
    bar, stream, clock = _progress(False, total=2, interval_s=5.0)
    clock.now = 106.0
    bar.update(2)  # due, and already the end
    bar.close()
    assert len(stream.getvalue().splitlines()) == 1


def test_on_a_terminal_one_self_overwriting_line() -> None:
    bar, stream, clock = _progress(True, total=4, rate_unit="ep/s")
    assert stream.getvalue().startswith("\reval [........................] 0/4 episodes")
    clock.now = 102.0
    bar.advance()
    assert stream.getvalue().count("\r") == 2
    assert "\reval [######..................] 1/4 episodes  0.50 ep/s  elapsed 0m02s  ETA 0m06s" in stream.getvalue()
    assert "\n" not in stream.getvalue()
    frame = stream.getvalue().split("\r")[-1]
    bar.clear()  # before other output to the terminal: the line blanked
    blank = stream.getvalue().split("\r")[-2]
    assert stream.getvalue().endswith("\r") and blank == " " * len(frame)
    clock.now = 108.0
    bar.update(4)
    bar.close()
    text = stream.getvalue()
    assert text.endswith("\n") and text.count("\n") == 1
    assert text.rstrip("\n").split("\r")[-1].startswith("eval [########################] 4/4 episodes")


def test_on_a_terminal_frames_are_padded_over_longer_ones() -> None:
    bar, stream, clock = _progress(True, total=2000)
    clock.now = 101.0
    bar.update(1500)  # "1,500/2,000", a rate and an ETA: longer than the first frame
    long_frame = stream.getvalue().split("\r")[-1]
    clock.now = 5000.0
    bar.update(1500)
    assert len(stream.getvalue().split("\r")[-1]) >= len(long_frame)


def test_the_rate_counts_this_run_only() -> None:
    """A resumed run (done > 0 at the start): rate and ETA from the units done since."""
    bar, stream, clock = _progress(False, total=100, done=50, interval_s=1.0)
    clock.now = 110.0
    bar.update(60)
    assert "60/100 episodes  1.00 episodes/s  elapsed 0m10s  ETA 0m40s" in stream.getvalue()


def test_no_stream_reports_nothing_and_a_closed_stream_is_not_a_terminal() -> None:
    bar = Progress("train", 5, "decisions", None)
    bar.update(3)
    bar.clear()
    bar.close()

    class Closed(FakeStream):
        def isatty(self) -> bool:
            raise ValueError("I/O operation on closed file")

    assert not Progress("train", 5, "decisions", Closed(True)).terminal


def test_duration() -> None:
    assert duration(0) == "0m00s"
    assert duration(61.4) == "1m01s"
    assert duration(3725) == "1h02m05s"
    assert duration(-3) == "0m00s"
    # the fixed-width form of train's line per iteration
    assert duration(61.4, hours=True) == "0h01m01s"
    assert duration(3725, hours=True) == "1h02m05s"
