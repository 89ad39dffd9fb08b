"""The one body of the programs' command lines (hrc_runtime.cli.run_program)."""

from __future__ import annotations

import logging
import os
import signal
import threading
import time

import pytest

from hrc_contract.config import ConfigError
from hrc_runtime.cli import run_program
from hrc_runtime.signals import StopEvent

log = logging.getLogger("test_cli")


def test_the_body_s_return_value_is_the_exit_code() -> None:
    with pytest.raises(SystemExit) as exit_:
        run_program("prog", "INFO", lambda stop: 3, log=log)
    assert exit_.value.code == 3


def test_an_invalid_configuration_is_one_line_and_exit_code_two(capsys: pytest.CaptureFixture[str]) -> None:
    def body(stop: StopEvent) -> int:
        raise ConfigError("robot 'ur5':\n   no such\tmodel")

    with pytest.raises(SystemExit) as exit_:
        run_program("prog", "INFO", body, log=log)
    assert exit_.value.code == 2
    assert capsys.readouterr().err == "prog: invalid configuration: robot 'ur5': no such model\n"


def test_sigterm_sets_the_stop_event_the_body_waits_on() -> None:
    """What systemd's stop does: the body's stop event is set, the body returns, the program exits with its code."""
    previous = signal.getsignal(signal.SIGTERM)

    def body(stop: StopEvent) -> int:
        threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGTERM)).start()
        deadline_s = time.monotonic() + 10.0
        while not stop.wait(0.02):  # the main thread runs between waits: Python handles the signal there
            if time.monotonic() > deadline_s:
                return 1
        return 0

    with pytest.raises(SystemExit) as exit_:
        run_program("prog", "INFO", body, log=log)
    assert exit_.value.code == 0
    assert signal.getsignal(signal.SIGTERM) == previous  # the handler is put back
