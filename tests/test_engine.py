"""The one rollout engine (``sim.rollout.run``): its two controllers and its one noise sampler.

The training rollouts feed back the information state Z_t built by shifting
in each measurement (``InfoStateFeedback``); a finished policy runs the
estimator recursion of its ``Controller``, which with the raw filter
(``policy.raw_filter``) reconstructs the same deviation Z_t - Z_bar_t. Run
through the one engine with the same noise, both must command the same
controls and see the same measurements: that checks the recursion, the shift
and the engine's handling of the noise together.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.control.policy import Controller, raw_filter
from podilqr_jax.identify.info_state import info_dim, info_states
from podilqr_jax.sim.rollout import Policy, open_loop_policy, rollout_batch, run_batch
from podilqr_jax.task.noise import NoiseLevels, sample

HORIZON = 12
Q = 2
BATCH = 3


def test_information_state_feedback_and_the_raw_estimator_are_one_controller():
    env = pj.make_task("pendulum-partial").replace(horizon=HORIZON, noise=pj.NoiseModel.paper(0.05))
    dims, data = env.dims, env.data
    T, nu, nz = dims.horizon, dims.nu, dims.nz
    nZ = info_dim(nz, nu, Q)
    u_bar = 0.5 * jnp.sin(jnp.arange(T, dtype=float))[:, None] * jnp.ones((T, nu))
    zero = jnp.zeros((T, nu))
    nominal = rollout_batch(dims, Q, data, open_loop_policy(u_bar, nZ), zero, zero)
    Z_bar = info_states(nominal.z, nominal.u, Q)
    K = -0.3 * jax.random.uniform(jax.random.PRNGKey(1), (T, nu, nZ))
    noise = sample(jax.random.PRNGKey(2), data.noise, BATCH, T)

    training = rollout_batch(dims, Q, data, Policy(u_bar, Z_bar[:-1], K), zero, zero, noise=noise)

    F, G, L = raw_filter(T, nz, nu, Q)
    controller = Controller(u_bar, nominal.z, K, F, G, L)
    limits = (data.u_low, data.u_high)
    episode = jax.jit(
        lambda c, n: run_batch(
            dims, data, c, n, data.x0, limits, batch=BATCH, in_axes=(None, 0, None), record_measured=True
        )
    )(controller, noise)

    # The feedback is not negligible: closed loop differs from the nominal's controls.
    assert float(jnp.max(jnp.abs(training.u - u_bar))) > 1e-3
    np.testing.assert_allclose(np.asarray(episode.u), np.asarray(training.u), rtol=0, atol=1e-10)
    np.testing.assert_allclose(np.asarray(episode.z), np.asarray(training.z), rtol=0, atol=1e-10)


def test_one_sampler_draws_the_same_noise_with_or_without_actuator_noise():
    """The sysid noise (no actuator term) and an episode's (with one) come from
    the same key split: adding actuator noise leaves dx0, w and v as they were."""
    levels = NoiseLevels(jnp.full(4, 0.1), jnp.full(4, 0.01), jnp.full(2, 0.02))
    key = jax.random.PRNGKey(7)
    plain = sample(key, levels, 5, 9)
    with_a = sample(key, levels._replace(a=jnp.full(1, 0.3)), 5, 9)
    assert plain.a is None and with_a.a.shape == (5, 9, 1)
    for name in ("dx0", "w", "v"):
        np.testing.assert_array_equal(np.asarray(getattr(plain, name)), np.asarray(getattr(with_a, name)))
    assert plain.w.shape == (5, 9, 4) and plain.v.shape == (5, 10, 2)
    assert float(jnp.std(with_a.a)) > 0.1
