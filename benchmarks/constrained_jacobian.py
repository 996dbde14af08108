"""MJX's exact Jacobians through tendons, a joint limit, an equality and a contact.

A two-link arm driven through a fixed tendon (tendon actuator), its shoulder
against its joint limit, the elbow tied to the shoulder by a joint equality,
and a ball pressed onto the floor (contact) pushed by a second motor. The
model-based reference's ``linearise`` (``jax.jacfwd`` through ``mjx.step``)
is compared with central finite differences of the same control step; the
error shrinks as eps^2, so the derivative is that of the simulated dynamics
(docs/third_party.md).

    python benchmarks/constrained_jacobian.py
"""

import os
import tempfile

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

import podilqr_jax as pj
from podilqr_jax.sim.rollout import physics_step, state_of, with_state

MODEL = """
<mujoco model="constrained">
  <option timestep="0.01"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="arm" pos="0 0 0.5">
      <joint name="a" type="hinge" axis="0 1 0" limited="true" range="-0.5 0.5" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.5"/>
      <body name="arm2" pos="0.3 0 0">
        <joint name="b" type="hinge" axis="0 1 0" damping="0.1"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.3"/>
      </body>
    </body>
    <body name="block" pos="0.5 0 0.048">
      <joint name="s" type="slide" axis="1 0 0" damping="0.5"/>
      <geom type="sphere" size="0.05" mass="0.2"/>
    </body>
  </worldbody>
  <tendon><fixed name="ab"><joint joint="a" coef="1"/><joint joint="b" coef="-0.5"/></fixed></tendon>
  <equality><joint joint1="b" joint2="a" polycoef="0 0.5 0 0 0"/></equality>
  <actuator>
    <motor name="tendon_motor" tendon="ab" gear="2" ctrllimited="true" ctrlrange="-3 3"/>
    <motor name="push" joint="s" gear="1"/>
  </actuator>
</mujoco>
"""


def main() -> None:
    path = os.path.join(tempfile.mkdtemp(), "constrained.xml")
    with open(path, "w") as f:
        f.write(MODEL)
    env = pj.Env.from_xml(path, substeps=2, horizon=4, x0={"qpos": [0.52, 0.26, 0.0]})
    dims, data = env.dims, env.data
    d0 = mjx.make_data(data.model)
    step = jax.jit(lambda x, u: state_of(physics_step(dims, data.model, with_state(dims, d0, x), u)))
    x, u = data.x0, jnp.array([0.5, 0.3])
    lin = pj.linearise(dims, data, jnp.stack([x] * 5), jnp.stack([u] * 4))
    print("| eps | max abs error of A (max abs A) | max abs error of B (max abs B) |\n|---|---|---|")
    for eps in (1e-4, 1e-5, 1e-6):
        A = np.stack([(step(x + eps * e, u) - step(x - eps * e, u)) / (2 * eps) for e in jnp.eye(dims.nx)], 1)
        B = np.stack([(step(x, u + eps * e) - step(x, u - eps * e)) / (2 * eps) for e in jnp.eye(dims.nu)], 1)
        print(
            f"| {eps:g} | {np.abs(A - lin.A[0]).max():.2e} ({np.abs(A).max():.3g}) "
            f"| {np.abs(B - lin.B[0]).max():.2e} ({np.abs(B).max():.3g}) |"
        )


if __name__ == "__main__":
    main()
