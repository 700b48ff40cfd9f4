"""``areasearch ros2`` on bad input: one ``areasearch: error: ...`` line and exit status 2, never a
traceback; without the ``ros2`` extra, the line says how to install it (this test needs no ROS)."""

from __future__ import annotations

import os
import sys

import pytest

from areasearch.cli import main


def _error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """Run the command in this process; its one error line (exit status 2, nothing else on stderr but ROS's log)."""
    code = main(list(args))
    out, err = capsys.readouterr()
    assert code == 2, (out, err)
    errors = [line for line in err.splitlines() if line.startswith("areasearch: error: ")]
    assert len(errors) == 1 and "Traceback" not in err, err
    return errors[0]


def test_without_the_extra_the_command_says_how_to_install_it(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "rclpy", None)  # `import rclpy` raises ImportError
    line = _error(capsys, "ros2", "--robots", "r1")
    assert line.startswith("areasearch: error: the ROS 2 node needs the ros2 extra: pip install 'areasearch[ros2]'")


@pytest.fixture
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("rclpy", reason="the ros2 extra is not installed (pip install 'areasearch[ros2]'): no rclpy")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@pytest.mark.usefixtures("ros_domain")
@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--robots", "1r"], "parameter robots: '1r' is not a ROS namespace"),
        (["--ros-args", "-p", "seed:=3"], "no robots: give their namespaces"),
        (["--robots", "r1", "--method", "nosuch"], "nosuch"),
        (["--robots", "r1", "--method", "greedy", "--weights", "x/policy"], "greedy"),
        (
            ["--robots", "r1", "--period-s", "2", "--ros-args", "-p", "period_s:=3.0"],
            "period_s given twice: --period-s 2",
        ),
        (["--robots", "r1", "--ros-args", "-p", "pose_source:=tf"], "pose_source must be one of amcl, odom"),
        (
            ["--robots", "r1", "--ros-args", "-p"],
            "--ros-args: failed to initialize rcl: Couldn't parse trailing -p flag",
        ),
    ],
)
def test_bad_settings_are_one_error_line(capsys: pytest.CaptureFixture[str], args: list[str], words: str) -> None:
    assert words in _error(capsys, "ros2", *args)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--period-s", "0"], "argument --period-s: expected a number in [0.05, 86400] (seconds), got '0'"),
        (["--pose-source", "tf"], "argument --pose-source: invalid choice: 'tf'"),
        (["--ros-args", "-p", "seed:=1", "--", "extra"], "unrecognized arguments: -- extra"),
    ],
)
def test_a_malformed_command_line_is_refused_by_the_parser(
    capsys: pytest.CaptureFixture[str], args: list[str], words: str
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["ros2", "--robots", "r1", *args])
    assert exc.value.code == 2
    assert words in capsys.readouterr().err
