"""The command line's common contract: --help everywhere, one-line errors with status 2."""

import subprocess
import sys

import pytest

from testbed.cli import main

COMMANDS = ["analytic", "captive", "simulate", "identify", "analyze", "check", "replay"]


@pytest.mark.parametrize("command", COMMANDS)
def test_help(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert "usage: testbed " + command in capsys.readouterr().out


def test_usage_error_is_one_line_status_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--scenario" in err


def test_python_dash_m():
    out = subprocess.run([sys.executable, "-m", "testbed", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "identify" in out.stdout
