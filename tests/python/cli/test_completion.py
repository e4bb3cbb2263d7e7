"""`fap completion bash|zsh`: the script shtab generates from the parsers,
and bash completing with it for real: a bash under tmux, keys typed,
the screen read back (tmux and bash may be missing only outside CI)."""
from __future__ import annotations

import os
import shutil
import subprocess
import time
import uuid
from pathlib import Path
from typing import Callable, Iterator

import pytest

from .conftest import run_proc


def test_completion_bash_and_zsh_scripts(fap) -> None:
    bash = fap("completion", "bash")
    assert bash.code == 0 and bash.err == ""
    assert "complete" in bash.out and "monitor" in bash.out and "--protocol" in bash.out
    zsh = fap("completion", "zsh")
    assert zsh.code == 0 and zsh.out.startswith("#compdef fap")
    assert "--protocol" in zsh.out


def test_completion_json(fap) -> None:
    import json

    r = fap("completion", "zsh", "--json")
    obj = json.loads(r.out)
    assert obj["event"] == "completion" and obj["shell"] == "zsh"
    assert obj["script"] == fap("completion", "zsh").out


def test_completion_unknown_shell_is_a_usage_error(fap) -> None:
    r = fap("completion", "fish")
    assert r.code == 2 and "shell" in r.err


def _need(tool: str) -> str:
    path = shutil.which(tool)
    if path is None:
        if os.environ.get("CI"):
            pytest.fail(f"{tool} missing (CI installs it: .ci/run)")
        pytest.skip(f"{tool} missing")
    return path


@pytest.fixture
def bash_in_tmux(tmp_path: Path) -> Iterator[Callable[[str, str], str]]:
    """type(keys, expect) -> screen: types into an interactive bash that has
    sourced `fap completion bash`, waits (deadline 10 s) for expect on screen."""
    tmux = _need("tmux")
    bash = _need("bash")
    script = run_proc("completion", "bash")
    assert script.code == 0, script.err
    (tmp_path / "fap.bash").write_text(script.out)
    rc = tmp_path / "bashrc"
    rc.write_text(f"PS1='$ '\nsource {tmp_path / 'fap.bash'}\n")
    sock = f"fap-completion-{uuid.uuid4().hex[:8]}"
    base = [tmux, "-L", sock, "-f", "/dev/null"]
    env = dict(os.environ, TERM="xterm", HOME=str(tmp_path))
    subprocess.run(base + ["new-session", "-d", "-x", "150", "-y", "20",
                           f"{bash} --noprofile --rcfile {rc} -i"], check=True, env=env)

    def screen() -> str:
        return subprocess.run(base + ["capture-pane", "-p"], check=True, capture_output=True,
                              text=True).stdout

    def type_(keys: str, expect: str) -> str:
        subprocess.run(base + ["send-keys", "-t", "0", "C-u"], check=True)
        subprocess.run(base + ["send-keys", "-t", "0", "-l", keys], check=True)
        subprocess.run(base + ["send-keys", "-t", "0", "Tab"], check=True)
        deadline = time.monotonic() + 10
        while True:
            text = screen()
            if expect in text or time.monotonic() > deadline:
                return text
            time.sleep(0.05)   # polling the screen; the condition has a deadline

    try:
        # the prompt shows once bashrc (and the completion script) is sourced
        deadline = time.monotonic() + 10
        while "$" not in screen().split() and time.monotonic() < deadline:
            time.sleep(0.05)
        yield type_
    finally:
        subprocess.run(base + ["kill-server"], check=False, capture_output=True)


def test_bash_completes_commands_and_options(bash_in_tmux) -> None:
    screen = bash_in_tmux("fap mon", "fap monitor")   # tmux trims the space after it
    assert "$ fap monitor" in screen, screen
    screen = bash_in_tmux("fap monitor --prot", "--protocol")
    assert "$ fap monitor --protocol" in screen, screen
    screen = bash_in_tmux("fap exec mas", "fap exec master")
    assert "$ fap exec master" in screen, screen
