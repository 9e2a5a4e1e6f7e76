"""Files written whole or not at all, and one run per directory (torchpark/files.py): real
kills (SIGKILL in the middle of a write), a full disk (RLIMIT_FSIZE) and a second process
holding the lock, each in a subprocess."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import torch

from torchpark.files import (
    LOCK_NAME,
    DirectoryInUse,
    locked,
    save_torch,
    stale_temporaries,
    write_file,
    write_text,
)


def python(code: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=timeout)


def test_a_file_is_replaced_whole(tmp_path):
    path = write_text(tmp_path / "table.md", "old")
    assert write_text(path, "new") == path and path.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]


def test_a_writer_that_fails_leaves_the_previous_file_and_no_temporary(tmp_path):
    path = write_text(tmp_path / "table.md", "old")

    def half_then_fail(tmp: Path) -> None:
        tmp.write_text("half")
        raise KeyError("the writer's own error")

    with pytest.raises(KeyError, match="the writer's own error"):
        write_file(path, half_then_fail)
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]


@pytest.mark.slow
def test_sigkill_in_the_middle_of_a_write_leaves_the_previous_file_whole(tmp_path):
    path = tmp_path / "checkpoint.pt"
    save_torch({"weights": torch.arange(10)}, path)
    before = path.read_bytes()
    killed = python(f"""
        import os, pathlib, signal
        import torch
        from torchpark.files import save_torch

        def dies_half_way(self, data):
            with open(self, "wb") as f:
                f.write(bytes(data)[:len(data) // 2])
            os.kill(os.getpid(), signal.SIGKILL)

        pathlib.Path.write_bytes = dies_half_way
        save_torch({{"weights": torch.zeros(100_000)}}, {str(path)!r})
    """)
    assert killed.returncode == -9, killed.stderr
    assert path.read_bytes() == before
    assert torch.equal(torch.load(path, weights_only=True)["weights"], torch.arange(10))
    assert len(stale_temporaries(tmp_path)) == 1  # what the killed writer left
    with locked(tmp_path):  # the next one to lock the directory clears it
        assert stale_temporaries(tmp_path) == []


@pytest.mark.slow
def test_a_full_disk_is_one_line_naming_the_file_and_leaves_the_previous_file(tmp_path):
    path = tmp_path / "checkpoint.pt"
    save_torch({"weights": torch.arange(10)}, path)
    before = path.read_bytes()
    full = python(f"""
        import resource
        import torch
        from torchpark.files import WriteError, save_torch, write_text
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        for write in (lambda: save_torch({{"weights": torch.zeros(100_000)}}, {str(path)!r}),
                      lambda: write_text({str(path)!r}, "x" * 10_000)):
            try:
                write()
            except WriteError as err:
                print(err)
    """)
    assert full.returncode == 0, full.stderr
    lines = full.stdout.splitlines()
    assert len(lines) == 2 and all(line.startswith(f"cannot write {str(path)!r}: ")
                                   for line in lines), lines
    assert "File too large" in lines[1]
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


@pytest.mark.slow
def test_a_directory_is_locked_by_one_process_until_it_ends(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import time
            from torchpark.files import locked
            with locked({str(tmp_path)!r}):
                print("held", flush=True)
                time.sleep(600)
        """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(DirectoryInUse, match=rf"logger.log_dir '{tmp_path}' is in use by "
                                                 rf"another run \(it holds {LOCK_NAME}\)"):
            with locked(tmp_path, "logger.log_dir"):
                pass
    finally:
        holder.kill()  # SIGKILL: the lock goes with the process
        holder.wait()
    deadline = time.monotonic() + 10
    while True:
        try:
            with locked(tmp_path):
                break
        except DirectoryInUse:
            assert time.monotonic() < deadline
            time.sleep(0.1)


def test_a_directory_that_cannot_be_made_is_named(tmp_path):
    (tmp_path / "file").write_text("a file, not a directory")
    with pytest.raises(ValueError, match=r"--out '.*file/run' cannot be created"):
        with locked(tmp_path / "file" / "run", "--out"):
            pass


