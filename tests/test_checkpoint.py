"""Never lose a run: checkpoints, resume, Ctrl-C, and same seed same result."""

import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import podilqr_jax as pj

ARRAYS = ("controls", "states", "K", "k")
HISTORIES = ("cost_history", "true_cost_history", "alpha_history", "mu_history", "grad_norm_history")


def _assert_same(a: pj.Result, b: pj.Result) -> None:
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in HISTORIES:
        assert getattr(a, name) == getattr(b, name), name
    assert (a.iterations, a.rollouts, a.rejected_steps, a.remeasured) == (
        b.iterations,
        b.rollouts,
        b.rejected_steps,
        b.remeasured,
    )


@pytest.fixture(scope="module")
def noisy_task():
    """The noisy pendulum of tests/test_noise.py and of the CLI runs below; solved with
    ``n_s`` at its default, as there, so that all of them run the same compiled programs."""
    return pj.make_task("pendulum-full", horizon=10, noise="paper")


def test_resume_gives_the_uninterrupted_result(noisy_task, tmp_path):
    """Under noise (both PRNG streams, re-measured nominals and mu in play):
    4 iterations with checkpoints every 2, then resumed to 7, equal 7 straight."""
    cfg = pj.default_config(noisy_task, max_iterations=7, seed=3)
    straight = pj.solve(noisy_task, cfg)
    first = pj.solve(noisy_task, cfg.replace(max_iterations=4), checkpoint=tmp_path, checkpoint_every=2)
    assert first.iterations == 4
    assert sorted(os.listdir(tmp_path)) == ["checkpoint.npz"]  # no temporary files left
    resumed = pj.solve(noisy_task, cfg, resume=tmp_path)
    _assert_same(straight, resumed)


def test_resume_of_a_noiseless_solve_that_reuses_its_model(tmp_path):
    """Noiseless, a rejected step keeps the identified model for the retry;
    checkpointing after every iteration must carry it."""
    env = pj.make_task("cartpole-full", horizon=12)
    # open-loop identification with every direction fitted: this run rejects a step (the defaults do not)
    cfg = pj.default_config(env, n_s=12, max_iterations=30, variant="plain", cap_rank=False, adapt_sigma=False)
    straight = pj.solve(env, cfg)
    assert straight.rejected_steps > 0, "the check needs a run with a rejected step"
    stop_at = straight.alpha_history.index(0.0) + 1  # just after the first rejection
    pj.solve(env, cfg.replace(max_iterations=stop_at), checkpoint=tmp_path, checkpoint_every=1)
    _assert_same(straight, pj.solve(env, cfg, resume=tmp_path))
    # A finished solve's checkpoint resumes to the same result, with nothing to do.
    done = pj.solve(env, cfg, checkpoint=tmp_path / "done", checkpoint_every=1000)
    again = pj.solve(env, cfg, resume=tmp_path / "done")
    assert again.status == done.status and again.message.startswith(done.message.split(";")[0])
    _assert_same(done, again)


def test_resume_refuses_another_task_or_settings(noisy_task, tmp_path):
    cfg = pj.default_config(noisy_task, max_iterations=2)
    pj.solve(noisy_task, cfg, checkpoint=tmp_path, checkpoint_every=1)
    with pytest.raises(pj.ConfigError, match=r"sigma: 0.01 -> 0.02"):
        pj.solve(noisy_task, cfg.replace(sigma=0.02), resume=tmp_path)
    with pytest.raises(pj.ConfigError, match="another solve: .*task"):
        pj.solve(noisy_task.replace(R=3.0, name="other"), cfg, resume=tmp_path)
    with pytest.raises(pj.ConfigError, match="No checkpoint"):
        pj.solve(noisy_task, cfg, resume=tmp_path / "missing")
    whole = (tmp_path / "checkpoint.npz").read_bytes()
    for damaged in (b"not a checkpoint", b"", whole[: len(whole) // 2]):  # garbage, empty, cut short
        (tmp_path / "checkpoint.npz").write_bytes(damaged)
        with pytest.raises(pj.ConfigError, match="cannot be read: it is empty, cut short or not a podilqr") as err:
            pj.solve(noisy_task, cfg, resume=tmp_path)
        assert "pickled" not in str(err.value) and "checkpoint.npz" in str(err.value)
    with pytest.raises(pj.ConfigError, match="checkpoint_every"):
        pj.solve(noisy_task, cfg, checkpoint=tmp_path, checkpoint_every=0)


def test_same_seed_same_result_bit_for_bit(noisy_task):
    """Two solves with the same seed agree exactly, counters included; another seed differs."""
    cfg = pj.default_config(noisy_task, max_iterations=4, seed=11)
    a, b = pj.solve(noisy_task, cfg), pj.solve(noisy_task, cfg)
    _assert_same(a, b)
    c = pj.solve(noisy_task, cfg.replace(seed=12))
    assert not np.array_equal(a.controls, c.controls)


# `podilqr` with SIGINT as a terminal delivers it: a test runner started in the background
# (`nohup pytest &`) ignores SIGINT and its children inherit that, so the child puts Python's
# default handler back before the CLI runs (in Python: a preexec_fn would make Popen fork a
# multithreaded process).
_CLI_WITH_CTRL_C = (
    "import runpy, signal, sys\n"
    "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
    "for s in (signal.SIGTERM, signal.SIGHUP, signal.SIGUSR1): signal.signal(s, signal.SIG_DFL)\n"
    "sys.argv = ['podilqr'] + sys.argv[1:]\n"
    "runpy.run_module('podilqr_jax.cli', run_name='__main__')\n"
)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGUSR1])
def test_ctrl_c_writes_the_result_and_exits_cleanly(tmp_path, signum):
    """SIGINT (Ctrl-C), or a scheduler's SIGTERM, SIGHUP or SIGUSR1, during
    `podilqr solve`: exit 128 + the signal's number, no traceback, a complete
    result file with status `interrupted`, and a checkpoint that resumes to the
    uninterrupted result bit for bit. The signal is sent the moment the first
    checkpoint appears, wherever the process is then (saving, the next
    iteration, a JAX callback): the solve only reads the request at an
    iteration boundary, so where it lands does not matter."""
    out, ckpt = tmp_path / "result.json", tmp_path / "ckpt"
    cmd = [sys.executable, "-c", _CLI_WITH_CTRL_C, "solve", "pendulum-full", "--noise", "paper"]
    cmd += ["--set", "max_iterations=100000", "--set", "horizon=10", "--out", str(out), "--no-plots"]
    cmd += ["--checkpoint", str(ckpt), "--every", "1", "--quiet"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 240
    while not (ckpt / "checkpoint.npz").exists():
        assert proc.poll() is None and time.time() < deadline, proc.stderr.read() if proc.poll() else "timeout"
        time.sleep(0.05)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, err
    assert "Traceback" not in err and "Exception ignored" not in err and "interrupted" in err
    assert "stopping after the current iteration" in err
    name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
    assert f"interrupted by {name}" in err
    d = json.loads(out.read_text())
    assert d["status"] == "interrupted" and d["iterations"] >= 1 and name in d["message"]
    assert np.all(np.isfinite(d["controls"])) and np.all(np.isfinite(d["K"]))
    assert len(d["cost_history"]) == d["iterations"] + 1
    if signum == signal.SIGTERM:  # the final checkpoint resumes to the uninterrupted solve (in-process)
        env = pj.make_task("pendulum-full", noise="paper").replace(horizon=10)
        cfg = pj.default_config(env, max_iterations=d["iterations"] + 2)
        _assert_same(pj.solve(env, cfg), pj.solve(env, cfg, resume=ckpt))


def _sigint_later(delay_s: float) -> None:
    threading.Timer(delay_s, os.kill, (os.getpid(), signal.SIGINT)).start()


@pytest.mark.parametrize("after_iteration, delay_s", [(0, None), (1, 0.0), (3, 0.002)])
def test_sigint_at_any_moment_stops_at_an_iteration_boundary(
    noisy_task, tmp_path, after_iteration, delay_s, python_sigint
):
    """In-process: a SIGINT before the first iteration (``delay_s`` None: sent
    synchronously while the handler is on) or at an arbitrary moment after
    iteration ``after_iteration`` (from another thread) returns a consistent
    result with status `interrupted` whose checkpoint resumes to exactly the
    uninterrupted solve."""
    import podilqr_jax.ilqr.interrupts as interrupts

    cfg = pj.default_config(noisy_task, max_iterations=500, seed=3)

    def callback(info):
        if info.iteration == after_iteration:
            _sigint_later(delay_s)

    with interrupts.deferred_interrupts as deferred:
        assert deferred.active
        if delay_s is None:
            os.kill(os.getpid(), signal.SIGINT)
            assert deferred.requested
        cut = pj.solve(noisy_task, cfg, callback=callback, checkpoint=tmp_path, checkpoint_every=1000)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    assert cut.status == pj.Status.INTERRUPTED
    assert after_iteration <= cut.iterations < after_iteration + 50
    assert len(cut.cost_history) == cut.iterations + 1 == len(cut.true_cost_history)
    assert np.all(np.isfinite(cut.controls)) and np.all(np.isfinite(cut.K))
    more = cfg.replace(max_iterations=cut.iterations + 3)
    _assert_same(pj.solve(noisy_task, more), pj.solve(noisy_task, more, resume=tmp_path))


def test_a_format_2_checkpoint_resumes_as_written(noisy_task, tmp_path):
    """Format 2 wrote the counters and histories flat, under the driver's old
    names; format 3 keeps them as the result's record. A checkpoint rewritten
    into format 2's layout resumes to the same result as format 3's."""
    from podilqr_jax.ilqr.checkpoint import _FORMAT_2_NAMES, FILE

    cfg = pj.default_config(noisy_task, max_iterations=5, seed=4)
    new, old = tmp_path / "3", tmp_path / "2"
    pj.solve(noisy_task, cfg.replace(max_iterations=3), checkpoint=new, checkpoint_every=1)
    with np.load(new / FILE) as npz:
        arrays = {k: npz[k] for k in npz.files}
    header = json.loads(str(arrays.pop("header")))
    assert header["format"] == 3 and header["record"]["iterations"] == 3
    record = header.pop("record")
    old_names = {v: k for k, v in _FORMAT_2_NAMES.items()}
    header.update({old_names.get(k, k): v for k, v in record.items()}, format=2)
    os.makedirs(old)
    np.savez(old / FILE, header=np.array(json.dumps(header)), **arrays)
    _assert_same(pj.solve(noisy_task, cfg, resume=new), pj.solve(noisy_task, cfg, resume=old))
