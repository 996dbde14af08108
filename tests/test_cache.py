"""The persistent compilation cache (podilqr_jax.compilation.cache): written where documented,
nothing in the working directory, switched off by PODILQR_CACHE=0, a user's own
JAX cache left alone, and a warm run gives the same result as a cold one.

Each case is a fresh interpreter: the cache is set up once, on import.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

PROBE = """
import json, jax, jax.numpy as jnp
import podilqr_jax as pj
jax.jit(lambda x: jnp.sin(x) * 2.0)(jnp.arange(3.0)).block_until_ready()
info = pj.cache_info()
print(json.dumps({"info": info._asdict(), "dir": jax.config.jax_compilation_cache_dir,
                  "min_time": jax.config.jax_persistent_cache_min_compile_time_secs}))
"""

SOLVE = """
import json
import podilqr_jax as pj
from podilqr_jax.compilation import stages
from podilqr_jax.compilation.compile_watch import CompileWatch
env = pj.make_task("pendulum-full", horizon=8)
with CompileWatch() as watch:
    r = pj.solve(env, pj.default_config(env, max_iterations=2, n_s=8))
print(json.dumps({"costs": r.cost_history, "K": r.K.ravel().tolist(), "compiles": watch.compiles,
                  "loads": watch.cache_loads, "stages": stages.counts, "fallbacks": stages.fallbacks}))
"""


def _run(code: str, tmp_path, stderr_to: list | None = None, **env_vars) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PODILQR_CACHE_DIR", "PODILQR_CACHE", "XDG_CACHE_HOME")}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["HOME"] = str(tmp_path / "home")  # never the real ~/.cache
    env.update(env_vars)
    work = tmp_path / "work"
    work.mkdir(exist_ok=True)
    out = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert list(work.iterdir()) == [], "something was written into the working directory"
    if stderr_to is not None:
        stderr_to.append(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _entries(path) -> int:
    return sum(1 for p in path.iterdir() if p.name.endswith("-cache")) if path.is_dir() else 0


def test_default_folder_is_under_the_user_cache_dir(tmp_path):
    got = _run(PROBE, tmp_path, XDG_CACHE_HOME=str(tmp_path / "xdg"))
    folder = tmp_path / "xdg" / "podilqr_jax" / "jax"
    assert got["info"]["source"] == "podilqr" and got["dir"] == str(folder)
    assert got["min_time"] == 0.0  # every stage is cached, not only those compiling for > 1 s
    assert _entries(folder) >= 1 and got["info"]["entries"] == _entries(folder)
    assert not (tmp_path / "home" / ".cache").exists()


def test_home_cache_without_xdg(tmp_path):
    got = _run(PROBE, tmp_path)
    assert got["dir"] == str(tmp_path / "home" / ".cache" / "podilqr_jax" / "jax")
    assert _entries(tmp_path / "home" / ".cache" / "podilqr_jax" / "jax") >= 1


def test_cache_dir_variable_moves_it_and_switch_disables_it(tmp_path):
    moved = tmp_path / "elsewhere"
    got = _run(PROBE, tmp_path, PODILQR_CACHE_DIR=str(moved))
    assert got["dir"] == str(moved) and _entries(moved) >= 1

    off = tmp_path / "off"
    got = _run(PROBE, tmp_path, PODILQR_CACHE_DIR=str(off), PODILQR_CACHE="0")
    assert got["info"]["source"] == "off" and not got["info"]["enabled"]
    assert got["dir"] is None and not off.exists()
    assert not (tmp_path / "home" / ".cache").exists()


def test_a_cache_configured_for_jax_is_left_alone(tmp_path):
    theirs = tmp_path / "theirs"
    got = _run(PROBE, tmp_path, JAX_COMPILATION_CACHE_DIR=str(theirs), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    assert got["info"]["source"] == "jax" and got["dir"] == str(theirs)
    assert got["min_time"] == 1.0  # JAX's default threshold, untouched
    assert not (tmp_path / "xdg").exists()


def test_warm_run_loads_from_disk_and_gives_the_same_result(tmp_path):
    folder = str(tmp_path / "cache")
    cold = _run(SOLVE, tmp_path, PODILQR_CACHE_DIR=folder)
    warm = _run(SOLVE, tmp_path, PODILQR_CACHE_DIR=folder)
    # A cold run may load a few executables it compiled itself earlier (the
    # same program reached twice); a warm run loads every one.
    assert cold["compiles"] > 5 and cold["loads"] < cold["compiles"] // 2
    assert warm["loads"] == warm["compiles"] == cold["compiles"]
    assert warm["costs"] == cold["costs"] and warm["K"] == cold["K"]  # bit for bit
    # The traced stages too (podilqr_jax/compilation/stages.py): the cold run exports the
    # sysid batch, the fit, the backward pass and the line search; the warm run
    # reads all of them and traces none.
    assert cold["fallbacks"] == {} and cold["stages"] == {"exported": 4, "loaded": 0}
    assert warm["stages"] == {"exported": 0, "loaded": 4}
    assert len(os.listdir(os.path.join(folder, "podilqr-stages"))) == 4

    # Two stage files swapped (or damaged): each is dropped with a line saying
    # so and traced afresh, and the run gives the same numbers.
    stage_dir = os.path.join(folder, "podilqr-stages")
    a, b = sorted(os.listdir(stage_dir))[:2]
    pa, pb = os.path.join(stage_dir, a), os.path.join(stage_dir, b)
    os.rename(pa, pa + ".x")
    os.rename(pb, pa)
    os.rename(pa + ".x", pb)
    swapped = _run(SOLVE, tmp_path, PODILQR_CACHE_DIR=folder, stderr_to=(err := []))
    assert swapped["stages"] == {"exported": 2, "loaded": 2}
    assert swapped["costs"] == cold["costs"] and swapped["K"] == cold["K"]
    assert err[0].count("dropped the cached stage") == 2 and "another key" in err[0]

    # A cache that is read and not written (PODILQR_CACHE=read, or a folder
    # without write permission): everything loads, nothing is written.
    before = sorted(os.listdir(folder)), sorted(os.listdir(stage_dir))
    shared = _run(SOLVE, tmp_path, PODILQR_CACHE_DIR=folder, PODILQR_CACHE="read")
    assert shared["stages"] == {"exported": 0, "loaded": 4}
    assert shared["loads"] == shared["compiles"] == cold["compiles"]
    assert shared["costs"] == cold["costs"] and shared["K"] == cold["K"]
    assert (sorted(os.listdir(folder)), sorted(os.listdir(stage_dir))) == before


def test_traced_stages_are_not_kept_without_the_package_cache(tmp_path):
    # On MuJoCo's C engine (nothing of MJX to compile): with the package's cache on, this solve
    # keeps its fit and backward pass (2 stages; the rollout stages run C code, tests/test_native.py).
    solve = SOLVE.replace("n_s=8)", "n_s=8, engine='native')")
    assert solve != SOLVE
    folder = tmp_path / "off"
    got = _run(solve, tmp_path, PODILQR_CACHE_DIR=str(folder), PODILQR_CACHE="0")
    assert got["stages"] == {"exported": 0, "loaded": 0} and not folder.exists()
    theirs = tmp_path / "theirs"
    got = _run(solve, tmp_path, JAX_COMPILATION_CACHE_DIR=str(theirs))
    assert got["stages"] == {"exported": 0, "loaded": 0} and not (theirs / "podilqr-stages").exists()


def test_an_unwritable_folder_warns_and_runs_without_a_cache(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    code = "import warnings\nwarnings.simplefilter('always')\n" + PROBE
    env = {k: v for k, v in os.environ.items() if k not in ("PODILQR_CACHE", "JAX_COMPILATION_CACHE_DIR")}
    env.update(PODILQR_CACHE_DIR=str(blocker / "cache"), HOME=str(tmp_path / "home"))
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["info"]["source"] == "unwritable" and got["dir"] is None
    assert "PODILQR_CACHE_DIR" in out.stderr and "PODILQR_CACHE=0" in out.stderr


def test_a_folder_without_write_permission_is_read(tmp_path):
    folder = tmp_path / "shared"
    folder.mkdir()
    # As root every folder is writable: the probe takes the permission away
    # the way ``os.access`` reports it for another user.
    code = (
        "import os\n_access = os.access\n"
        f"os.access = lambda p, m, **k: False if m & os.W_OK and str(p).startswith({str(folder)!r}) "
        "else _access(p, m, **k)\n" + PROBE
    )
    got = _run(code, tmp_path, stderr_to=(err := []), PODILQR_CACHE_DIR=str(folder))
    assert got["info"]["source"] == "podilqr" and got["info"]["read_only"] and got["dir"] == str(folder)
    assert got["min_time"] > 1e20 and _entries(folder) == 0  # read, never written
    assert "is read-only: reading it, writing nothing" in err[0] and err[0].count("podilqr_jax:") == 1


def test_a_stage_key_hashes_the_source_of_every_subpackage():
    """A traced stage kept on disk is keyed on the package's source: an edit of
    the line search or the fit (outside sim/, where the stages module lives)
    must start afresh, or a warm run would execute the program of old code."""
    import podilqr_jax
    from podilqr_jax.compilation import stages

    files = stages.source_files()
    assert os.path.samefile(stages.PACKAGE_ROOT, os.path.dirname(podilqr_jax.__file__))
    for rel in ("__init__.py", "ilqr/line_search.py", "identify/sysid.py", "task/env.py", "sim/rollout.py"):
        assert rel.replace("/", os.sep) in files, rel
