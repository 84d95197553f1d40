"""Atomic outputs (workbench.core.atomic): a write is whole or absent, never partial,
and never over an input file.

On SIGKILL nothing can run, so the hidden temporary file
(``.<stem>.<random>.tmp<suffix>`` in the destination folder) stays behind;
that is the accepted cost: the destination itself is absent or holds its
previous, complete content, and no reader ever sees a partial file under the
output's name. An exception (including KeyboardInterrupt) removes the
temporary file too.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from workbench.core.atomic import atomic_path, check_not_input, save_npz, write_text
from workbench.core.errors import InputError


def test_raise_mid_write_leaves_nothing(tmp_path):
    dest = tmp_path / "out.json"
    with pytest.raises(RuntimeError, match="disk on fire"):
        with atomic_path(dest) as tmp:
            tmp.write_text('{"half": ')
            raise RuntimeError("disk on fire")
    assert list(tmp_path.iterdir()) == []


def test_interrupt_mid_write_keeps_previous_content(tmp_path):
    dest = tmp_path / "model.npz"
    save_npz(dest, A=np.eye(2))
    before = dest.read_bytes()
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(dest, suffix=".npz") as tmp:
            tmp.write_bytes(b"PK\x03\x04 partial")
            raise KeyboardInterrupt
    assert dest.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["model.npz"]


def test_successful_write_replaces_whole(tmp_path):
    dest = tmp_path / "a.txt"
    write_text(dest, "old")
    write_text(dest, "new")
    assert dest.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


_KILLED_WRITER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    import numpy.lib._npyio_impl as npyio
    from workbench.core.atomic import save_npz

    real = npyio.format.write_array

    def slow_write_array(*args, **kwargs):
        real(*args, **kwargs)      # one array is on disk (in the temporary file) ...
        print("writing", flush=True)
        time.sleep(60)             # ... and the writer is killed before the next

    npyio.format.write_array = slow_write_array
    save_npz(sys.argv[1], a=np.zeros(200_000), b=np.ones(200_000))
    """
)


@pytest.mark.parametrize("existing", [False, True], ids=["new-file", "over-old-file"])
def test_sigkill_mid_write_leaves_no_partial_output(tmp_path, existing):
    dest = tmp_path / "big.npz"
    if existing:
        save_npz(dest, old=np.arange(3))
    before = dest.read_bytes() if existing else None
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(dest)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    try:
        assert proc.stdout.readline().strip() == "writing"
        proc.kill()  # SIGKILL: no cleanup handler can run
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    if existing:
        assert dest.read_bytes() == before
        assert list(np.load(dest).keys()) == ["old"]
    else:
        assert not dest.exists()
    # the hidden temporary file is what SIGKILL leaves: never under the output's name
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "big.npz"]
    assert len(leftovers) == 1
    assert leftovers[0].startswith(".big.") and leftovers[0].endswith(".tmp.npz")


def test_check_not_input_refuses_same_file_by_any_spelling(tmp_path, monkeypatch):
    data = tmp_path / "data.npz"
    data.write_bytes(b"x")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    for spelling in ["data.npz", "./data.npz", "sub/../data.npz", str(data)]:
        with pytest.raises(InputError, match="refusing to write the output over an input file"):
            check_not_input(spelling, [str(data)])
    link = tmp_path / "link.npz"
    link.symlink_to(data)
    with pytest.raises(InputError):
        check_not_input(link, [data])
    check_not_input(tmp_path / "other.npz", [data, None])  # a different file is fine


def test_written_files_get_the_mode_open_would_give(tmp_path):
    """A result is shared like any file the user writes: 0666 under the umask, not
    mkstemp's 0600."""
    import os

    from workbench.core.atomic import write_text

    old = os.umask(0o022)
    try:
        write_text(tmp_path / "report.html", "<p>x</p>")
    finally:
        os.umask(old)
    assert (tmp_path / "report.html").stat().st_mode & 0o777 == 0o644
