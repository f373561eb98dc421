"""Faults beyond bad files: the disk fills while a checkpoint or a dataset is written,
the run directory or the dataset cache is read-only, two writers share one run directory, the
dataset cache is damaged between runs. Each: one ``error:`` line (or one ``note:`` and the
command goes on), nothing partial left, no earlier result lost."""

from __future__ import annotations

import builtins
import contextlib
import dataclasses
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from amorctl.cli.main import main
from amorctl.core import files
from amorctl.core.dir_lock import LOCK_FILE, dir_lock
from amorctl.core.errors import AmorError, AmorNote
from amorctl.core.files import StorageError, check_writable
from amorctl.train.checkpoint import list_checkpoints, load_checkpoint
from amorctl.train.loop import train_run

torch.set_num_threads(1)

TOY_TOML = """
[run]
iterations = 2
checkpoint_every = 2
keep_checkpoints = 0
tensorboard = false
threads = 1
[env]
kind = "toy"
num_envs = 16
episode_seconds = 0.3
[network]
actor_hidden = [8]
critic_hidden = [8]
[ppo]
precision = "fp32"
num_steps = 4
num_epochs = 1
num_minibatches = 1
"""


def run_cli(capsys: pytest.CaptureFixture, *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_error(err: str) -> str:
    """The single ``error:`` line of a failed command's stderr (asserts there is exactly one line)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    return lines[0]


def tree(directory: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()
    }


def leftovers(directory: Path) -> list[str]:
    """Temporary files of atomic writes and lock files left under ``directory``."""
    return sorted(
        str(p.relative_to(directory))
        for p in directory.rglob("*")
        if p.name.endswith(".tmp") or p.name == LOCK_FILE or p.name.startswith(".amorctl-write-probe")
    )


@pytest.fixture
def toy_run_dir(tmp_path: Path, capsys: pytest.CaptureFixture) -> Path:
    """A two-iteration toy run (checkpoint at iteration 2) made through the CLI."""
    cfg = tmp_path / "toy.toml"
    cfg.write_text(TOY_TOML)
    out = tmp_path / "run"
    code, _, err = run_cli(capsys, "train", "--config", cfg, "--out", out, "--json")
    assert code == 0, err
    assert [i for i, _ in list_checkpoints(out / "checkpoints")] == [2]
    return out


# --- disk full ------------------------------------------------------------------------------------
def _inject_enospc(monkeypatch: pytest.MonkeyPatch, where: str, name_part: str) -> list[Path]:
    """Make atomic writes of files whose temporary name contains ``name_part`` fail with ENOSPC:
    ``where="write"`` half-way through writing the data (a partial temporary file is on disk),
    ``where="fsync"`` when it is flushed (the whole temporary file is on disk). Returns the list
    of temporary paths that failed."""
    failed: list[Path] = []
    enospc = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    if where == "write":
        real_write = Path.write_bytes

        def write_bytes(self: Path, data: bytes) -> int:
            if name_part in self.name:
                real_write(self, data[: len(data) // 2])
                failed.append(self)
                raise enospc
            return real_write(self, data)

        monkeypatch.setattr(Path, "write_bytes", write_bytes)
    else:
        real_fsync = files._fsync

        def fsync(path: Path) -> None:
            if name_part in path.name:
                assert path.stat().st_size > 0  # the data is there: the flush is what fails
                failed.append(path)
                raise enospc
            real_fsync(path)

        monkeypatch.setattr(files, "_fsync", fsync)
    return failed


@pytest.mark.parametrize(("where", "file"), [("write", "safetensors"), ("fsync", "json")])
def test_disk_full_while_a_checkpoint_is_written_keeps_the_previous_one_resumable(
    toy_run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch,
    where: str, file: str,
) -> None:  # fmt: skip
    out = toy_run_dir
    before = tree(out / "checkpoints")
    failed = _inject_enospc(monkeypatch, where, f".iter_000004.{file}.")
    code, stdout, err = run_cli(capsys, "train", "--resume", "--out", out, "--iterations", "4", "--json")
    line = one_error(err)
    assert code == 2 and failed and stdout == ""
    assert f"iter_000004.{file}: cannot write (no space left on the device)" in line
    assert f"the newest complete checkpoint {out / 'checkpoints' / 'iter_000002.json'} is intact" in line
    assert f"amorctl train --resume --out {out}" in line
    assert tree(out / "checkpoints") == before  # the old checkpoint untouched, no half of the new one
    assert leftovers(out) == [] and not any(p.exists() for p in failed)

    monkeypatch.undo()  # space freed: resume from iteration 2 as if nothing had happened
    code, stdout, err = run_cli(capsys, "train", "--resume", "--out", out, "--iterations", "4", "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert (summary["start_iteration"], summary["end_iteration"]) == (2, 4)
    reference = tmp_path / "uninterrupted"
    cfg = tmp_path / "toy4.toml"
    cfg.write_text(TOY_TOML.replace("iterations = 2", "iterations = 4"))
    assert run_cli(capsys, "train", "--config", cfg, "--out", reference, "--json")[0] == 0
    a = load_checkpoint(out / "checkpoints/iter_000004.json").trainer.arrays
    b = load_checkpoint(reference / "checkpoints/iter_000004.json").trainer.arrays
    for key in b:  # the resumed run equals one that never hit the full disk
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    lines = (out / "metrics.csv").read_text().splitlines()
    assert [float(r.split(",")[0]) for r in lines[1:]] == [1, 2, 3, 4]  # rows 3, 4 once each


class FillingDisk:
    """A file whose writes fail with ENOSPC once 2 kB are in it (a disk filling up mid-stream)."""

    def __init__(self, f) -> None:  # type: ignore[no-untyped-def]
        self._f = f

    def write(self, data: bytes) -> int:
        if self._f.tell() + len(data) > 2000:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._f.write(data)

    def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
        return getattr(self._f, name)

    def __enter__(self) -> FillingDisk:
        return self

    def __exit__(self, *exc: object) -> None:
        self._f.close()


@pytest.mark.slow
def test_a_real_full_disk_during_a_checkpoint(toy_run_dir: Path, tmp_path: Path) -> None:
    """The kernel's own ENOSPC: the run on a 2 MB tmpfs (private mount namespace, root only) filled
    up to 12 kB, resumed: the 16 kB tensor file of the next checkpoint does not fit."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare to mount a small tmpfs")
    disk = tmp_path / "disk"
    disk.mkdir()
    run = disk / "run"
    train = f"{sys.executable} -m amorctl.cli.main train --resume --out {run} --iterations 4"
    script = f"""
mount -t tmpfs -o size=2m tmpfs {disk} || exit 97
cp -r {toy_run_dir} {run}
avail=$(df --output=avail -B1 {disk} | tail -1)
head -c $((avail - 12288)) /dev/zero > {disk}/filler
{train}; echo "rc=$?"
ls -a {run} {run}/checkpoints | tr '\\n' ' '; echo
rm {disk}/filler
{train} --json; echo "rc=$?"
"""
    proc = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    if "rc=" not in proc.stdout:
        pytest.skip(f"could not mount a tmpfs here: {proc.stderr.strip()[:200]}")
    first, second = proc.stdout.split("rc=")[1:3]
    assert first.startswith("2\n"), proc.stdout + proc.stderr
    line = one_error(proc.stderr)  # the first command's; the resumed one wrote nothing to stderr
    assert f"{run}/checkpoints/iter_000004.safetensors: cannot write (no space left on the device)" in line
    assert "iter_000002.json is intact" in line
    listing = first.split("\n")[1].split()
    assert ".amorctl.lock" not in listing and not [n for n in listing if n.endswith(".tmp")]
    assert [n for n in listing if n.startswith("iter_")] == ["iter_000002.json", "iter_000002.safetensors"]
    assert second.startswith("0") and '"end_iteration": 4' in proc.stdout


def test_disk_full_while_a_dataset_is_written_keeps_the_old_dataset(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from amorctl.motion.builtin import pybullet_data_path

    root = pybullet_data_path()
    if root is None:
        pytest.skip("pybullet_data is not installed: no DeepMimic clip to preprocess")
    clips = root / "data" / "motions"
    out = tmp_path / "ds.mcap"
    args = ("preprocess", "--character", "humanoid36", "--out", out, "--no-vae", "--json")
    code, _, err = run_cli(capsys, *args, clips / "humanoid3d_walk.txt")
    assert code == 0, err
    old = out.read_bytes()

    for where in ("write", "fsync"):
        with monkeypatch.context() as m:
            if where == "write":  # the MCAP writer streams into the temporary file: fail mid-stream

                def filling_open(path, mode="r", *a, **k):  # type: ignore[no-untyped-def]
                    f = builtins.open(path, mode, *a, **k)  # noqa: SIM115 (returned open)
                    return FillingDisk(f) if ".ds.mcap." in str(path) and "w" in mode else f

                m.setattr("amorctl.motion.dataset.open", filling_open, raising=False)
            else:
                _inject_enospc(m, "fsync", ".ds.mcap.")
            code, stdout, err = run_cli(capsys, *args, clips / "humanoid3d_run.txt")
        line = one_error(err)
        assert code == 2 and stdout == "", where
        assert f"{out}: cannot write (no space left on the device)" in line, where
        assert out.read_bytes() == old, where  # the earlier dataset is still there, unchanged
        assert sorted(p.name for p in tmp_path.iterdir()) == ["ds.mcap"], where  # no temporary file


def test_a_storage_error_outside_atomic_writes_is_one_line(
    toy_run_dir: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """metrics.csv is appended to, not written atomically: a full disk there is one line too."""
    from amorctl.train import metrics

    def write(self, m):  # type: ignore[no-untyped-def]
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))

    monkeypatch.setattr(metrics.MetricsLog, "write", write)
    code, _, err = run_cli(capsys, "train", "--resume", "--out", toy_run_dir, "--iterations", "4")
    assert code == 2
    assert one_error(err) == (
        f"error: {toy_run_dir / 'metrics.csv'}: cannot write (no space left on the device); "
        "free space there (or write elsewhere) and run again"
    )


# --- read-only run directory and cache ------------------------------------------------------------
@contextlib.contextmanager
def read_only(*dirs: Path) -> Iterator[list[str]]:
    """A command prefix under which ``dirs`` are read-only. As root (where permission bits do not
    stop writes) a private read-only bind mount in a new mount namespace (``unshare -m``; the
    mounts vanish with the command); otherwise ``chmod a-w`` for the block."""
    if os.geteuid() != 0:
        modes = {d: d.stat().st_mode for d in dirs}
        for d in dirs:
            d.chmod(0o555)
        try:
            yield []
        finally:
            for d, mode in modes.items():
                d.chmod(mode)
        return
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"]).returncode != 0:
        pytest.skip("running as root without mount namespaces: no way to make a folder read-only")
    script = (
        'for d in "$@"; do [ "$d" = -- ] && break; '
        'mount --bind "$d" "$d" && mount -o remount,bind,ro "$d" || exit 97; shift; done; shift; exec "$@"'
    )
    yield ["unshare", "-m", "--propagation", "private", "sh", "-c", script, "sh", *map(str, dirs), "--"]


def run_read_only(prefix: list[str], *args: object, env: dict[str, str] | None = None):  # type: ignore[no-untyped-def]
    proc = subprocess.run(
        [*prefix, sys.executable, *map(str, args)], capture_output=True, text=True, env=env, timeout=300
    )
    if proc.returncode == 97:
        pytest.skip("could not mount a read-only bind here")
    return proc


def test_a_read_only_run_directory_is_refused_before_any_work(toy_run_dir: Path) -> None:
    before = tree(toy_run_dir)
    with read_only(toy_run_dir) as prefix:
        proc = run_read_only(
            prefix, "-m", "amorctl.cli.main", "train", "--resume", "--out", toy_run_dir, "--iterations", "4"
        )
    line = one_error(proc.stderr)
    assert proc.returncode == 2
    assert line.startswith(f"error: {toy_run_dir}: the run directory is not writable (")
    assert "read-only file system" in line or "permission denied" in line
    assert "copy the run to a writable place" in line
    assert proc.stdout == ""  # no header, no iteration: refused before the env was built
    assert tree(toy_run_dir) == before


def test_a_read_only_cache_is_refused_before_preprocessing(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    cache.mkdir()
    cfg = tmp_path / "tracking.toml"
    cfg.write_text(
        '[run]\niterations = 1\ntensorboard = false\nthreads = 1\n[env]\nkind = "tracking"\n'
        'character = "biped20"\nnum_envs = 2\n'
    )
    marker = tmp_path / "preprocess-ran"
    program = (  # the CLI, with preprocessing replaced by a tripwire
        "import sys\nimport amorctl.motion.cache as cache\nfrom amorctl.cli.main import main\n"
        "def tripwire(*a, **k):\n    open(sys.argv[1], 'w').write('ran')\n    raise SystemExit(99)\n"
        "cache.preprocess = tripwire\nsys.exit(main(sys.argv[2:]))\n"
    )
    env = {**os.environ, "AMORCTL_CACHE_DIR": str(cache)}
    with read_only(cache) as prefix:
        proc = run_read_only(
            prefix, "-c", program, marker, "train", "--config", cfg, "--out", tmp_path / "run", env=env
        )
    line = one_error(proc.stderr)
    assert proc.returncode == 2 and not marker.exists()
    assert line.startswith(f"error: {cache / 'datasets'}: the dataset cache is not writable (")
    assert "set AMORCTL_CACHE_DIR to a writable folder" in line
    assert not (tmp_path / "run").exists()  # the new run left nothing


def test_check_writable_names_the_folder_and_probes_the_nearest_existing_parent(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    check_writable(tmp_path / "not" / "yet", "run directory")  # the parent is writable: fine
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # the probe leaves nothing
    probed: list[str] = []

    def refusing_mkstemp(prefix: str = "", dir: str = "", **_: object):  # type: ignore[no-untyped-def]
        probed.append(str(dir))
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(files.tempfile, "mkstemp", refusing_mkstemp)
    with pytest.raises(StorageError) as info:
        check_writable(tmp_path / "not" / "yet", "run directory")
    assert probed == [str(tmp_path)]
    assert str(info.value) == (
        f"{tmp_path / 'not' / 'yet'}: the run directory is not writable (read-only file system); "
        "make it writable or choose another place"
    )


# --- one writer per run directory -----------------------------------------------------------------
HOLD = (
    "import sys, time\nfrom amorctl.core.dir_lock import dir_lock\n"
    "with dir_lock(sys.argv[1]):\n    print('locked', flush=True)\n    time.sleep(600)\n"
)


@contextlib.contextmanager
def lock_holder(folder: Path) -> Iterator[subprocess.Popen]:
    """Another process holding ``folder``'s lock; killed (SIGKILL) at the end of the block."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        yield proc
    finally:
        proc.kill()
        proc.wait()


def test_a_second_writer_is_refused_and_a_killed_holders_lock_is_recovered(
    toy_run_dir: Path, capsys: pytest.CaptureFixture
) -> None:
    out = toy_run_dir
    before = tree(out)
    with lock_holder(out) as holder:
        code, stdout, err = run_cli(capsys, "train", "--resume", "--out", out, "--iterations", "4")
        line = one_error(err)
        assert code == 2 and stdout == ""
        assert line.startswith(
            f"error: {out} is in use by process {holder.pid} (lock file {out / LOCK_FILE}, since "
        )
        assert f"wait for it to finish or stop it (kill {holder.pid}), then run again" in line
        assert {k: v for k, v in tree(out).items() if k != LOCK_FILE} == before
        with pytest.raises(AmorError, match=f"in use by process {holder.pid}"):  # the library too
            train_run(load_config_of(out), out, resume=True)
    # the holder was killed with SIGKILL: its lock file is still there, naming a dead process
    assert json.loads((out / LOCK_FILE).read_text())["pid"] == holder.pid
    code, stdout, err = run_cli(capsys, "train", "--resume", "--out", out, "--iterations", "4", "--json")
    assert code == 0, err
    assert err.strip().splitlines() == [
        f"note: {out / LOCK_FILE}: recovered a stale lock left by process {holder.pid} "
        "(it is no longer running; killed or crashed?)"
    ]
    assert json.loads(stdout)["end_iteration"] == 4
    assert not (out / LOCK_FILE).exists()  # released at the end


def load_config_of(out: Path):  # type: ignore[no-untyped-def]
    from amorctl.train.rundir import RunDir

    return RunDir(out).config


def test_the_lock_is_held_once_per_process_and_released(tmp_path: Path) -> None:
    folder = tmp_path / "d"
    with dir_lock(folder) as path:
        holder = json.loads(path.read_text())
        assert holder["pid"] == os.getpid()
        with pytest.raises(AmorError, match=f"in use by process {os.getpid()}"), dir_lock(folder):
            pass
        assert path.exists()  # the refused attempt did not remove the holder's file
    assert not path.exists()
    with dir_lock(folder):  # free again
        pass


def test_a_second_hlp_train_on_the_same_directory_is_refused(
    toy_run: Path, toy_hlp_config: Any, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    from amorctl.hlp.run import train_hlp

    hd = tmp_path / "hlp"
    train_hlp(toy_run, hd, toy_hlp_config)
    before = tree(hd)
    with lock_holder(hd) as holder:
        code, _, err = run_cli(capsys, "hlp", "train", toy_run, "--out", hd, "--resume", "--iterations", "2")
        line = one_error(err)
        assert code == 2 and f"{hd} is in use by process {holder.pid} (lock file" in line
        assert "two writers would corrupt the HLP directory" in line
        assert {k: v for k, v in tree(hd).items() if k != LOCK_FILE} == before
    code, _, err = run_cli(
        capsys, "hlp", "train", toy_run, "--out", hd, "--resume", "--iterations", "2", "--json"
    )
    assert code == 0, err
    assert f"note: {hd / LOCK_FILE}: recovered a stale lock left by process {holder.pid}" in err
    assert [i for i, _ in list_checkpoints(hd / "checkpoints")] == [1, 2] and not (hd / LOCK_FILE).exists()
    # a new HLP refused for another reason leaves no directory (nor the lock's) behind
    code, _, err = run_cli(capsys, "hlp", "train", toy_run, "--out", tmp_path / "new" / "h", "--motion", "x")
    assert code == 2 and not (tmp_path / "new").exists()


@pytest.mark.slow
def test_two_real_train_resumes_at_once_and_a_kill_9(toy_run_dir: Path) -> None:
    """Two `amorctl train --resume` processes on one run: the second is refused naming the first;
    the first killed with SIGKILL mid-run leaves its lock, and the next resume recovers it."""
    out = toy_run_dir
    cmd = [sys.executable, "-m", "amorctl.cli.main", "train", "--resume", "--out", str(out)]
    first = subprocess.Popen([*cmd, "--iterations", "100000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len((out / "metrics.csv").read_text().splitlines()) < 5:
            time.sleep(0.2)  # training (header + 2 old rows + 2 new ones)
        assert first.poll() is None
        second = subprocess.run([*cmd, "--iterations", "100000"], capture_output=True, text=True, timeout=300)
        assert second.returncode == 2 and f"is in use by process {first.pid}" in one_error(second.stderr)
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=60)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    third = subprocess.run([*cmd, "--iterations", "4", "--json"], capture_output=True, text=True, timeout=300)
    assert third.returncode == 0, third.stderr
    assert f"recovered a stale lock left by process {first.pid}" in third.stderr
    assert json.loads(third.stdout)["end_iteration"] >= 4


# --- a damaged cache -------------------------------------------------------------------------------
def test_a_damaged_cached_dataset_is_found_by_its_hash_and_rebuilt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion import cache
    from amorctl.motion.dataset import load_dataset, write_dataset
    from amorctl.registry import get_registry

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=1.0, seed=3)
    builds: list[Path] = []

    def fake_preprocess(files, *, character, out, **_):  # type: ignore[no-untyped-def]
        builds.append(out)
        write_dataset(out, dataclasses.replace(lib, character=character))

    monkeypatch.setattr(cache, "preprocess", fake_preprocess)
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path))
    path = cache.default_dataset("biped20")
    record = path.with_name(path.name + ".sha256")
    assert len(builds) == 1 and record.read_text().strip() == files.file_sha256(path)
    assert cache.default_dataset("biped20") == path and len(builds) == 1  # intact: used as it is

    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one bit of damage between runs
    path.write_bytes(bytes(data))
    with pytest.warns(AmorNote) as notes:
        assert cache.default_dataset("biped20") == path
    assert len(builds) == 2 and len(notes) == 1
    assert str(notes[0].message) == (
        f"{path}: the cached file is damaged (its SHA-256 differs from the one recorded when it was "
        "built); rebuilding the built-in dataset (a few minutes)"
    )
    assert len(load_dataset(path).clips) == 2 and record.read_text().strip() == files.file_sha256(path)

    record.unlink()  # cached before hash records existed: checked by its own hashes, then recorded
    assert cache.default_dataset("biped20") == path and len(builds) == 2 and record.is_file()
    record.unlink()
    path.write_bytes(path.read_bytes()[:-500])  # ... and damaged: rebuilt too
    with pytest.warns(AmorNote, match="the cached file is damaged"):
        cache.default_dataset("biped20")
    assert len(builds) == 3 and len(load_dataset(path).clips) == 2


def test_train_rebuilds_a_damaged_cache_with_one_note(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion import cache
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=1.0, seed=3)
    monkeypatch.setattr(cache, "preprocess", lambda files, *, out, **_: write_dataset(out, lib))
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path / "cache"))
    path = cache.default_dataset("biped20")
    path.write_bytes(path.read_bytes()[:-100])
    cfg = tmp_path / "tracking.toml"
    cfg.write_text(
        '[run]\niterations = 1\ntensorboard = false\nthreads = 1\n[env]\nkind = "tracking"\n'
        'character = "biped20"\nnum_envs = 2\nepisode_seconds = 0.4\n[network]\nactor_hidden = [8]\n'
        "critic_hidden = [8]\n[ppo]\nnum_steps = 4\nnum_epochs = 1\nnum_minibatches = 1\n"
    )
    code, stdout, err = run_cli(capsys, "train", "--config", cfg, "--out", tmp_path / "run", "--json")
    assert code == 0, err
    assert err.strip().splitlines() == [
        f"note: {path}: the cached file is damaged (its SHA-256 differs from the one recorded when it "
        "was built); rebuilding the built-in dataset (a few minutes)"
    ]
    assert json.loads(stdout)["end_iteration"] == 1
