"""Demonstrations: the HDF5 store (append, resume, validation) and ``driveopt collect``."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from learned_data import SCENARIO, synthetic_rows, write_synthetic

from driveopt.cli import main
from driveopt.data.demonstrations import DatasetError, DemonstrationWriter, EpisodeKey, load_demonstrations
from driveopt.experiments.collect import collect


def _entry(episode: int, rows: int = 8, seed: int = 0) -> dict:
    return {"scenario": SCENARIO, "seed": seed, "episode": episode, "env_seed": episode, "collided": False, "duration": rows / 10.0}


def _writer(path) -> DemonstrationWriter:
    return DemonstrationWriter(path, {"expert": "synthetic"}, 100, 22, 55)


def test_round_trip_and_episode_table(tmp_path):
    path = write_synthetic(tmp_path / "d.h5", episodes=3, rows=10)
    data = load_demonstrations(path)
    assert len(data) == 30 and data.trajectory.shape == (30, 100, 2)
    assert list(data.episodes["num_rows"]) == [10, 10, 10] and list(data.episodes["first_row"]) == [0, 10, 20]
    assert np.array_equal(data.episode, np.repeat([0, 1, 2], 10))
    assert np.all(np.isinf(data.time_to_crash()))
    both = load_demonstrations([path, write_synthetic(tmp_path / "e.h5", episodes=2, rows=5, seed=1)])
    assert len(both) == 40 and both.episode[-1] == 4


def test_partial_episode_is_truncated_on_reopen(tmp_path):
    path = write_synthetic(tmp_path / "d.h5", episodes=2, rows=8)
    with h5py.File(path, "a") as f:  # rows of an episode whose entry was never written (killed mid-write)
        for name in ("observation", "status", "episode"):
            f[name].resize(f[name].shape[0] + 5, axis=0)
    assert len(load_demonstrations(path)) == 16  # loading ignores the partial rows ...
    writer = _writer(path)  # ... and reopening removes them
    assert writer.done() == {EpisodeKey(SCENARIO, 0, 0), EpisodeKey(SCENARIO, 0, 1)}
    writer.append_episode({**_entry(2), "collided": True}, synthetic_rows(np.random.default_rng(3), 8))
    data = load_demonstrations(path)
    assert len(data) == 24 and all(f.shape[0] == 24 for f in (data.observation, data.status, data.trajectory))
    assert np.array_equal(data.episode, np.repeat([0, 1, 2], 8))
    assert data.time_to_crash()[-1] == pytest.approx(0.1)


class Killed(BaseException):
    """Stands for the process being killed: nothing after it runs (except closing the file)."""


@pytest.mark.parametrize(("dataset", "step"), [("/episodes/seed", "resize"), ("/episodes/first_row", "resize"),
                                               ("/episodes/num_rows", "resize"), ("/episodes/num_rows", "__setitem__")])
def test_torn_episode_entry_is_redone(tmp_path, monkeypatch, dataset, step):
    path = write_synthetic(tmp_path / "d.h5", episodes=2, rows=8)
    rows = synthetic_rows(np.random.default_rng(3), 8)
    original = getattr(h5py.Dataset, step)

    def killed_at(self, *args, **kwargs):  # the writer dies while writing ``dataset``: rows and earlier fields are on disk
        if self.name == dataset:
            raise Killed
        return original(self, *args, **kwargs)

    with monkeypatch.context() as m:
        m.setattr(h5py.Dataset, step, killed_at)
        with pytest.raises(Killed):
            _writer(path).append_episode(_entry(2), rows)
    torn = load_demonstrations(path)  # reading sees the complete episodes only
    assert len(torn) == 16 and len(torn.episodes["scenario"]) == 2
    writer = _writer(path)
    assert writer.done() == {EpisodeKey(SCENARIO, 0, 0), EpisodeKey(SCENARIO, 0, 1)}  # the rerun redoes episode 2
    writer.append_episode(_entry(2), rows)
    data = load_demonstrations(path)
    assert sorted(data.episodes["episode"]) == [0, 1, 2] and len(data) == 24
    assert np.array_equal(data.episode, np.repeat([0, 1, 2], 8))
    np.testing.assert_array_equal(data.trajectory[16:], rows["trajectory"])


def test_rows_of_the_wrong_shape_are_refused_before_writing(tmp_path):
    path = write_synthetic(tmp_path / "d.h5", episodes=2, rows=8)
    writer = _writer(path)
    bad = synthetic_rows(np.random.default_rng(3), 8)
    bad["trajectory"] = bad["trajectory"][:, :50]
    with pytest.raises(DatasetError, match="trajectory"):
        writer.append_episode(_entry(2), bad)
    good = synthetic_rows(np.random.default_rng(4), 8)
    writer.append_episode(_entry(2), good)  # the same writer, no reopening
    data = load_demonstrations(path)
    assert len(data) == 24 and np.array_equal(data.episode, np.repeat([0, 1, 2], 8))
    np.testing.assert_array_equal(data.observation[16:], good["observation"])


def test_same_episodes_have_the_same_fingerprint_in_any_file_order(tmp_path):
    a = write_synthetic(tmp_path / "a.h5", episodes=2, rows=8, seed=0)
    b = write_synthetic(tmp_path / "b.h5", episodes=2, rows=8, seed=1)
    ab, ba = load_demonstrations([a, b]), load_demonstrations([b, a])
    assert ab.fingerprint() == ba.fingerprint()
    assert [ab.episode_ids()[i] for i in np.argsort(ab.episode_rank())] == [ba.episode_ids()[i] for i in np.argsort(ba.episode_rank())]
    rng, other = np.random.default_rng(1), _writer(tmp_path / "c.h5")  # b's episodes, one value changed
    for episode in range(2):
        rows = synthetic_rows(rng, 8)
        rows["observation"][3, 2] += 1.0 if episode == 0 else 0.0
        other.append_episode(_entry(episode, seed=1), rows)
    assert load_demonstrations([a, tmp_path / "c.h5"]).fingerprint() != ab.fingerprint()


def test_bad_files_are_refused(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        load_demonstrations(tmp_path / "none.h5")
    (tmp_path / "junk.h5").write_bytes(b"not an hdf5 file at all")
    with pytest.raises(DatasetError, match="corrupted"):
        load_demonstrations(tmp_path / "junk.h5")
    path = write_synthetic(tmp_path / "d.h5", episodes=1, rows=4)
    with h5py.File(path, "a") as f:
        f.attrs["schema_version"] = 99
    with pytest.raises(DatasetError, match="schema version 99"):
        load_demonstrations(path)
    path = write_synthetic(tmp_path / "n.h5", episodes=1, rows=4)
    with h5py.File(path, "a") as f:
        f["trajectory"][1, 3, 0] = np.nan
    with pytest.raises(DatasetError, match="NaN"):
        load_demonstrations(path)
    with pytest.raises(DatasetError, match="other settings"):
        DemonstrationWriter(path, {"expert": "bilevel"}, 100, 22, 55)
    assert main(["train", "cvae", "--data", str(tmp_path / "junk.h5"), "--out", str(tmp_path / "o")]) == 2


def test_collect_resumes_without_duplicates(tmp_path):
    out = tmp_path / "demo.h5"
    kwargs = dict(seed=3, samples=40, iterations=1, duration=0.3, workers=1, progress=False)
    first = collect(out, ["two-lane-d1.0"], episodes=1, **kwargs)
    assert first["episodes"] == 1 and first["rows"] == 3
    before = load_demonstrations(out)
    second = collect(out, ["two-lane-d1.0"], episodes=2, **kwargs)  # the interrupted sweep, rerun larger
    assert second["skipped"] == 1 and second["episodes"] == 1
    assert collect(out, ["two-lane-d1.0"], episodes=2, **kwargs)["episodes"] == 0
    data = load_demonstrations(out)
    assert len(data) == 6 and sorted(data.episodes["episode"]) == [0, 1]
    np.testing.assert_array_equal(data.observation[:3], before.observation)
    assert data.observation.shape == (6, 55) and np.all(data.trajectory[:, 0, 0] == pytest.approx(0.0, abs=1e-3))
    assert np.allclose(data.trajectory[:, 0, 1], data.init_y[:, 0], atol=1e-3)  # plans start at the ego
    with pytest.raises(DatasetError, match="other settings"):
        collect(out, ["two-lane-d1.0"], episodes=2, **{**kwargs, "samples": 80})
    assert main(["collect", "--scenarios", "nowhere", "--out", str(out)]) == 2


@pytest.mark.parametrize("bad", [["--duration", "nan"], ["--duration", "inf"], ["--duration", "0"], ["--duration", "-1"],
                                 ["--scenarios", "nowhere"], ["--seed", "-1"], ["--seed", "200000000000000"],
                                 ["--seed", "42949"]])  # 42949 x 100003 + episode is beyond 2**32 - 1
def test_collect_checks_options_before_touching_the_file(tmp_path, capsys, bad):
    out = tmp_path / "sub" / "demo.h5"
    try:
        status = main(["collect", "--scenarios", "two-lane-d1.0", "--episodes", "1", "--out", str(out), *bad])
    except SystemExit as exc:  # a value the argument's type refuses: argparse exits
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: ") and err.count("\n") == 1 and bad[1] in err
    assert not out.exists() and not out.parent.exists()


def test_collect_into_a_directory_is_refused(tmp_path, capsys):
    folder = tmp_path / "folder"
    folder.mkdir()
    assert main(["collect", "--scenarios", "two-lane-d1.0", "--episodes", "1", "--out", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a directory" in err
    assert list(folder.iterdir()) == []


def test_terminated_collect_keeps_finished_episodes_and_resumes(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "demo.h5"
    # 2 s episodes (about a second of work each), so the poll below sees two finished ones long before the 40th
    args = [sys.executable, "-m", "driveopt.cli", "collect", "--scenarios", "two-lane-d1.0", "--episodes", "40",
            "--samples", "40", "--iterations", "1", "--duration", "2.0", "--seed", "5", "--out", str(out)]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env={**os.environ, "SDL_VIDEODRIVER": "offscreen"})
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        time.sleep(0.5)
        if out.exists():
            try:
                if len(load_demonstrations(out).episodes["num_rows"]) >= 2:
                    break
            except DatasetError:  # locked while the collector writes
                pass
    assert proc.poll() is None, "the collector finished before it could be interrupted"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 128 + signal.SIGTERM
    kept = load_demonstrations(out)
    finished = len(kept.episodes["num_rows"])
    assert 2 <= finished < 40
    summary = collect(out, ["two-lane-d1.0"], episodes=finished + 1, seed=5, samples=40, iterations=1, duration=2.0, progress=False)
    assert summary["skipped"] == finished and summary["episodes"] == 1
    data = load_demonstrations(out)
    assert sorted(data.episodes["episode"]) == list(range(finished + 1))


def _hold_open(path, mode: str, seconds: float):
    """A process that holds ``path`` open in ``mode`` for ``seconds``; returned once the file is open."""
    import subprocess
    import sys

    code = f"import h5py, sys, time\nf = h5py.File({str(path)!r}, {mode!r})\nprint('open', flush=True)\ntime.sleep({seconds})\nf.close()"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "open"
    return proc


@pytest.mark.parametrize("holder_mode", ["r", "a"])
def test_a_file_held_open_by_another_process_is_waited_for(tmp_path, holder_mode):
    path = write_synthetic(tmp_path / "d.h5", episodes=1, rows=8)
    holder = _hold_open(path, holder_mode, 1.0)  # e.g. `train` loading while `collect` writes
    _writer(path).append_episode(_entry(1), synthetic_rows(np.random.default_rng(1), 8))
    assert holder.wait(timeout=30) == 0
    holder = _hold_open(path, "a", 1.0)  # and a load while the collector writes
    assert len(load_demonstrations(path)) == 16
    holder.wait(timeout=30)


def test_a_file_held_longer_than_the_wait_is_a_clear_error(tmp_path, monkeypatch):
    import driveopt.data.demonstrations as demonstrations

    path = write_synthetic(tmp_path / "d.h5", episodes=1, rows=8)
    monkeypatch.setattr(demonstrations, "LOCK_WAIT_S", 0.3)
    holder = _hold_open(path, "a", 5.0)
    try:
        with pytest.raises(DatasetError, match="another process held it for over 0.3 s"):
            _writer(path).append_episode(_entry(1), synthetic_rows(np.random.default_rng(1), 8))
        with pytest.raises(DatasetError, match="another process held it"):
            load_demonstrations(path)
    finally:
        holder.kill()
        holder.wait()
    assert len(load_demonstrations(path)) == 8


def test_a_truncated_file_is_reported_as_corrupted_at_once(tmp_path, monkeypatch):
    import time

    from driveopt.data import demonstrations

    monkeypatch.setattr(demonstrations, "LOCK_WAIT_S", 20.0)
    path = write_synthetic(tmp_path / "d.h5", episodes=2, rows=8)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    start = time.monotonic()
    with pytest.raises(DatasetError) as info:
        load_demonstrations(path)
    assert time.monotonic() - start < 5.0  # not retried as if another process held the file
    assert "corrupted: truncated" in str(info.value) and "another process" not in str(info.value)
    with pytest.raises(DatasetError, match="corrupted: truncated"):
        _writer(path)


def test_only_hdf5s_lock_error_counts_as_a_held_file():
    from driveopt.data.demonstrations import _is_lock_error

    held = OSError(11, "Unable to synchronously open file (unable to lock file, errno = 11, error message = "
                       "'Resource temporarily unavailable')")
    truncated = OSError("Unable to synchronously open file (truncated file: eof = 326288, sblock->base_addr = 0, "
                        "stored_eof = 652576)")
    assert _is_lock_error(held) and not _is_lock_error(truncated)


def _load_or_error(path):
    try:
        return load_demonstrations(path)
    except DatasetError:
        return None


def _same(a, b) -> bool:
    arrays = [(getattr(a, name), getattr(b, name)) for name in ("observation", "init_x", "init_y", "lane_bounds",
                                                                "setpoints", "coeffs", "trajectory", "status",
                                                                "time", "episode")]
    arrays += [(a.episodes[name], b.episodes[name]) for name in b.episodes]
    arrays += list(zip(a.modes or (), b.modes or ()))
    return (a.modes is None) == (b.modes is None) and a.attrs == b.attrs and all(
        np.array_equal(x, y) for x, y in arrays)


def test_a_zeroed_block_anywhere_is_refused_or_harmless(tmp_path):
    """Every 4 KB block of a file zeroed in turn: the load refuses the file as corrupted, or returns exactly the
    rows written (the block held unused space); never different rows."""
    path = write_synthetic(tmp_path / "d.h5", episodes=3, rows=6)
    good, raw = load_demonstrations(path), path.read_bytes()
    damaged, refused = tmp_path / "damaged.h5", 0
    for offset in range(0, len(raw), 4096):
        block = raw[offset:offset + 4096]
        if not any(block):
            continue
        damaged.write_bytes(raw[:offset] + bytes(len(block)) + raw[offset + 4096:])
        loaded = _load_or_error(damaged)
        assert loaded is None or _same(loaded, good), f"a zeroed block at byte {offset} went unnoticed"
        refused += loaded is None
    assert refused >= 5


def test_a_changed_value_is_refused_as_corrupted(tmp_path):
    path = write_synthetic(tmp_path / "d.h5", episodes=2, rows=8)
    with h5py.File(path, "a") as f:  # as a flipped bit or a stray write would
        f["observation"][11, 2] += 1.0
    with pytest.raises(DatasetError, match=r"corrupted: episode 1 \(four-lane-d3.0, seed 0, episode 1\) does not match"):
        load_demonstrations(path)


def test_files_without_checksums_stay_readable_and_appendable(tmp_path):
    """A file written before driveopt stored checksums: read unchecked, as before."""
    path = write_synthetic(tmp_path / "d.h5", episodes=2, rows=8)
    with h5py.File(path, "a") as f:
        del f["episodes/checksum"]
        f["observation"][3, 2] += 1.0  # unnoticed without checksums
    _writer(path).append_episode(_entry(2), synthetic_rows(np.random.default_rng(1), 8))
    assert len(load_demonstrations(path)) == 24


def _disk_full_beyond(monkeypatch, limit: int) -> None:
    """``os.pwrite`` as on a disk with room for the files up to byte ``limit``: a write that ends beyond it fails with
    ENOSPC (overwriting bytes below it still works, as on a full disk)."""
    import errno
    import os

    real = os.pwrite

    def pwrite(fd, data, offset):
        if offset + len(memoryview(data).cast("B")) > limit:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, data, offset)

    monkeypatch.setattr(os, "pwrite", pwrite)


def test_a_write_that_finds_the_disk_full_leaves_the_file_as_it_was(tmp_path, monkeypatch):
    path = write_synthetic(tmp_path / "d.h5", episodes=2, rows=8)
    before = path.read_bytes()
    rows = synthetic_rows(np.random.default_rng(3), 300)  # more rows than the last chunks hold: new space is needed
    writer = _writer(path)
    with monkeypatch.context() as m:
        _disk_full_beyond(m, len(before))
        with pytest.raises(DatasetError) as info:
            writer.append_episode(_entry(2, rows=300), rows)
    message = str(info.value)
    assert "No space left on device" in message and "as it was before" in message and "\n" not in message
    assert path.read_bytes() == before  # not a byte changed: HDF5's metadata rewritten in place is restored
    writer.append_episode(_entry(2, rows=300), rows)  # the rerun, once there is room
    assert sorted(load_demonstrations(path).episodes["episode"]) == [0, 1, 2]


def test_a_file_the_full_disk_keeps_from_being_created_is_removed(tmp_path, monkeypatch, capsys):
    out = tmp_path / "demo.h5"
    with monkeypatch.context() as m:
        _disk_full_beyond(m, 0)
        assert main(["collect", "--scenarios", "two-lane-d1.0", "--episodes", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: cannot write demonstrations") and err.count("\n") == 1
    assert "No space left on device" in err and not out.exists()


def test_collect_on_a_real_full_disk_ends_in_one_line_and_resumes(tmp_path, capsys):
    """A 24 KB tmpfs (the lock and the file's empty schema fit, an episode does not); skipped where it cannot be mounted."""
    import subprocess

    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=24k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("a tmpfs cannot be mounted here (not root)")
    try:
        out = disk / "c.h5"
        args = ["collect", "--scenarios", "two-lane-d1.0", "--episodes", "1", "--samples", "40", "--iterations", "1",
                "--duration", "0.3", "--seed", "3", "--out", str(out)]
        assert main(args) == 2
        err = capsys.readouterr().err  # the progress bar's lines, then the error's one line
        assert err.split("\n")[-2].startswith("driveopt: error: cannot write demonstrations") and "Traceback" not in err
        assert len(load_demonstrations(out).episodes["num_rows"]) == 0  # the file as created, readable
        subprocess.run(["mount", "-o", "remount,size=4m", str(disk)], check=True)
        assert main(args) == 0  # the rerun resumes
        assert len(load_demonstrations(out).episodes["num_rows"]) == 1
    finally:
        subprocess.run(["umount", str(disk)], check=False)
