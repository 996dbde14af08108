"""Files written whole or not at all (podilqr_jax.atomic): the temporary file a
killed writer leaves is removed by the next write to its folder; one another
live process is writing is not."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from podilqr_jax import atomic
from podilqr_jax.atomic import write_json_atomic


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_the_next_write_removes_a_killed_writers_leftovers(tmp_path):
    host = atomic._host()
    dead = tmp_path / f".tmp-{_dead_pid()}@{host}~abc123.json"
    old_style = tmp_path / ".tmp-k2j3h4.npz"  # written before the pid was in the name
    other_host_new = tmp_path / f".tmp-12@{host}-elsewhere~x.json"
    other_host_old = tmp_path / f".tmp-13@{host}-elsewhere~y.json"
    for f in (dead, old_style, other_host_new, other_host_old):
        f.write_text("torn")
    day_ago = time.time() - atomic.STALE_S - 60
    for f in (old_style, other_host_old):
        os.utime(f, (day_ago, day_ago))
    with subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) as live:
        in_flight = tmp_path / f".tmp-{live.pid}@{host}~def456.npz"
        in_flight.write_text("being written")
        try:
            write_json_atomic(tmp_path / "result.json", {"cost": 1.5})
        finally:
            live.kill()
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted([in_flight.name, other_host_new.name, "result.json"])
    assert json.loads((tmp_path / "result.json").read_text()) == {"cost": 1.5}


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "result.json"
    write_json_atomic(target, {"cost": 1.0})

    def fail(f):
        f.write(b"{half")
        raise RuntimeError("killed mid-write")

    try:
        atomic.write_atomic(target, fail, suffix=".json")
    except RuntimeError:
        pass
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]
    assert json.loads(target.read_text()) == {"cost": 1.0}


def test_a_json_gets_the_permissions_open_would_give_and_the_umask_stays(tmp_path):
    before = os.umask(0o027)
    try:
        assert atomic._umask() == 0o027
        write_json_atomic(tmp_path / "r.json", {"cost": 1.0})
        assert (tmp_path / "r.json").stat().st_mode & 0o777 == 0o640
        assert os.umask(0o027) == 0o027  # read, not changed
    finally:
        os.umask(before)
