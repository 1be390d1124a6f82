"""Every CLI failure to write is exit code 2 and one line; files get the user's umask.

Output options whose folder cannot be written fail before the work starts; a write that fails
later (a full disk: a real tmpfs, or a real EFBIG under RLIMIT_FSIZE) still ends in one line
naming the file, with no temporary file left behind.
"""

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from kinematics.dataset import atomic_write, read_dataset, write_dataset
from learner.snapshot import atomic_write_bytes
from stream.cli import main

CLI = [sys.executable, "-c", "import sys; from stream.cli import main; sys.exit(main())"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "d.parquet"
    assert main(["sim", "dataset", "--n", "30", "--seed", "1", "--out", str(path)]) == 0
    return path


def _one_error_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    assert lines[0].startswith("robocal: error: ") and "Traceback" not in text
    return lines[0]


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "dataset", "--n", "20", "--out", "{file}/x.parquet"],
        ["train", "--data", "{data}", "--out", "{file}/m.safetensors"],
        ["continual", "--data", "{data}", "--out", "{file}/m.safetensors"],
        ["evaluate", "--model", "{file}", "--data", "{data}"],  # a reader: its own one line
        ["experiment", "paper", "--data", "{data}", "--out", "{file}/study/x"],
        ["hpo", "--data", "{data}", "--out", "{file}/m.safetensors"],
        ["calibrate", "--data", "{data}", "--out", "{file}/c.toml"],
        ["gap", "--data", "{data}", "--report", "{file}/report"],
        ["data", "summary", "{data}", "--hist", "{file}/h.png"],
        ["import", "ipa", "{file}", "--out", "{file}/x.parquet"],
        ["demo", "--out", "{file}/out/x"],
    ],
)
def test_an_output_under_a_file_is_one_line_and_exit_2(argv, dataset, tmp_path, capsys):
    file = tmp_path / "plain-file"
    file.write_text("not a folder")
    args = [a.format(file=file, data=dataset) for a in argv]
    assert main(args) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert str(file) in line
    assert file.read_text() == "not a folder" and sorted(tmp_path.iterdir()) == [file]


@pytest.mark.parametrize("hist", ["/proc/robocal-test.png", "/proc/robocal-test/h.png"])
def test_a_histogram_into_proc_is_one_line(hist, dataset, capsys):
    assert main(["data", "summary", str(dataset), "--hist", hist]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert hist in line and "cannot write there" in line


def test_a_folder_without_write_permission_is_one_line(tmp_path):
    """Root writes anywhere: as root the CLI runs without the capabilities that override file
    permissions (setpriv), otherwise as ourselves."""
    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("as root, a permission test needs setpriv (util-linux) to drop caps")
        prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search,-fowner"]
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    out = locked / "x.parquet"
    try:
        proc = subprocess.run(
            [*prefix, *CLI, "sim", "dataset", "--n", "20", "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=300,
        )
    finally:
        locked.chmod(0o755)
    assert proc.returncode == 2, proc.stderr
    line = _one_error_line(proc.stderr)
    assert str(out) in line and "Permission denied" in line
    assert list(locked.iterdir()) == []


def _assert_write_failed_cleanly(rc: int, stderr: str, out: Path, code: str) -> None:
    assert rc == 2, stderr
    assert "Traceback" not in stderr
    last = stderr.strip().splitlines()[-1]  # after the progress bar
    assert last.startswith("robocal: error: ") and f"[{code}]" in last and str(out) in last
    assert list(out.parent.iterdir()) == []  # no temporary file, no half-written dataset


def test_a_full_disk_is_one_line_and_leaves_no_temporary_file(tmp_path, capsys):
    mnt = tmp_path / "small"
    mnt.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip("mounting a 64 kB tmpfs needs root (the EFBIG test below runs anyway)")
    try:
        out = mnt / "x.parquet"
        rc = main(["sim", "dataset", "--n", "400", "--out", str(out)])
        _assert_write_failed_cleanly(rc, capsys.readouterr().err, out, "ENOSPC")
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def test_a_file_size_limit_is_one_line_and_leaves_no_temporary_file(tmp_path):
    """RLIMIT_FSIZE makes the dataset write fail part-way with a real EFBIG."""
    out = tmp_path / "out" / "x.csv"
    out.parent.mkdir()
    code = (
        "import resource, sys\n"
        "from stream.cli import main\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))\n"
        f"sys.exit(main(['sim', 'dataset', '--n', '200', '--out', {str(out)!r}]))\n"
    )
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env
    )
    _assert_write_failed_cleanly(proc.returncode, proc.stderr, out, "EFBIG")


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o077])
def test_files_are_written_with_the_umask(mask, dataset, tmp_path):
    old = os.umask(mask)
    try:
        ds = write_dataset(read_dataset(dataset), tmp_path / "d.csv")
        snap = atomic_write_bytes(tmp_path / "m.safetensors", b"weights")
        other = atomic_write(tmp_path / "x.txt", lambda tmp: Path(tmp).write_text("x"))
        assert main(["sim", "dataset", "--n", "20", "--out", str(tmp_path / "s.parquet")]) == 0
    finally:
        os.umask(old)
    want = 0o666 & ~mask
    written = [ds, ds.with_suffix(".meta.json"), snap, other, tmp_path / "s.parquet"]
    assert {p.name: oct(stat.S_IMODE(p.stat().st_mode)) for p in written} == {
        p.name: oct(want) for p in written
    }
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
