"""Issue 33 item 9: the completion scripts complete file names for every
option that takes a file or path (`--capture`, `--config`, `--port`, ...)
and directories for `--link-dir` & co, typed into a real bash under tmux;
the scripts' headers name the folders the shells read."""
from __future__ import annotations

from pathlib import Path

from .test_completion import bash_in_tmux  # noqa: F401  (the fixture)


def test_bash_completes_file_names(bash_in_tmux, tmp_path: Path) -> None:  # noqa: F811
    (tmp_path / "capture-one.cap").write_text("")
    (tmp_path / "bridge-site.toml").write_text("")
    (tmp_path / "ttyFAKE0").write_text("")
    (tmp_path / "links-dir").mkdir()
    for typed, expect in [
        (f"fap monitor --capture {tmp_path}/captu", f"{tmp_path}/capture-one.cap"),
        (f"fap bridge --config {tmp_path}/bridge-s", f"{tmp_path}/bridge-site.toml"),
        (f"fap exec master --port {tmp_path}/ttyF", f"{tmp_path}/ttyFAKE0"),
        (f"fap bus --link-dir {tmp_path}/links-", f"{tmp_path}/links-dir/"),
    ]:
        screen = bash_in_tmux(typed, expect)
        assert f"$ {typed.split(' ', 1)[0]} {typed.split(' ', 1)[1].rsplit('/', 1)[0]}" in screen
        assert expect in screen, (typed, screen)


def test_script_headers_name_the_right_folders(fap) -> None:
    bash = fap("completion", "bash").out
    head = bash.split("\n\n", 1)[0]
    assert "~/.local/share/bash-completion/completions/fap" in head
    assert "bash_completion/" not in bash.split("_shtab", 1)[0]   # shtab's wrong folder
    zsh = fap("completion", "zsh").out
    assert zsh.startswith("#compdef fap\n")
    assert "zsh_completion" not in zsh.split("_shtab", 1)[0] and "$fpath" in zsh.split("\n\n")[0]
