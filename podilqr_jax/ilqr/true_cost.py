"""Ground truth: what a policy learnt under noise is worth on the noiseless system.

Under noise the cost the algorithm sees (the training cost of a noisy nominal)
is itself random. What matters is the policy it learnt,

  u_t = u_bar_t + K_t (Z_t - Z_bar_t),

nominal controls plus the feedback gains on the information state. Its *true
cost* is that policy run once, closed loop, on the noiseless model from the
nominal start x0. The *open-loop replay* runs the nominal controls u_bar alone
on the same noiseless model. Both are one jitted batch-of-two rollout.

The two differ under noise because a noisy nominal is a record of one noisy
run: its controls carry the feedback's corrections to that run's noise, and a
swing-up that ends balancing upright amplifies any open-loop mismatch by
orders of magnitude over the horizon. The feedback gains undo the mismatch;
the open-loop replay cannot (see docs/noise.md).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..compilation.stages import stage
from ..sim.rollout import Policy, simulate
from ..task.env import EnvData, EnvDims
from .cost import batch_costs


class TrueCosts(NamedTuple):
    closed_loop: jnp.ndarray  # the policy's cost on the noiseless system
    open_loop: jnp.ndarray  # the nominal controls replayed open loop


@stage(static_argnames=("dims", "q"), outputs=(TrueCosts,))
def true_costs(dims: EnvDims, q: int, data: EnvData, policy: Policy) -> TrueCosts:
    """Closed-loop and open-loop cost of ``policy`` on the noiseless system."""
    zero = jnp.zeros((dims.horizon, dims.nu), policy.u_bar.dtype)
    gains = jnp.stack([policy.K, jnp.zeros_like(policy.K)])
    both = jax.vmap(lambda K: simulate(dims, q, data, policy._replace(K=K), zero, zero))(gains)
    costs, _ = batch_costs(both.z, both.u, data)
    return TrueCosts(costs[0], costs[1])
