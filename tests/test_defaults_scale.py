"""Defaults that scale with the model: n_s from the fit's regressors, and a 30-hinge chain with defaults only."""

import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.identify.info_state import n_regressors
from podilqr_jax.ilqr.config import MIN_N_S

LINKS = 30


def _chain_xml(links: int) -> str:
    """A planar chain of ``links`` hinged capsules hanging from a pivot, a motor at every hinge (no contacts)."""
    body = ""
    for i in reversed(range(links)):
        body = (
            f'<body name="l{i}" pos="0 0 {-0.1 if i else 0}"><joint name="j{i}" type="hinge" axis="0 1 0" '
            f'damping="0.05"/><geom type="capsule" size="0.02" fromto="0 0 0 0 0 -0.1" mass="0.1" '
            f'contype="0" conaffinity="0"/>{body}</body>'
        )
    motors = "".join(f'<motor joint="j{i}" ctrllimited="true" ctrlrange="-1 1"/>' for i in range(links))
    return (
        f'<mujoco><option timestep="0.01"/><worldbody><body pos="0 0 4">{body}</body></worldbody>'
        f"<actuator>{motors}</actuator></mujoco>"
    )


def _chain(tmp_path, horizon=5):
    path = tmp_path / "chain.xml"
    path.write_text(_chain_xml(LINKS))
    return pj.Env.from_xml(path, horizon=horizon, target=np.r_[np.full(LINKS, 0.05), np.zeros(LINKS)], QT=10.0)


def test_n_s_is_forty_or_twice_the_regressors(tmp_path):
    assert pj.default_config(pj.make_task("cartpole-partial")).n_s == MIN_N_S  # 2 x 6 regressors is less
    chain = _chain(tmp_path)
    p = n_regressors(chain.dims.nz, chain.dims.nu, 1)
    assert p == 3 * LINKS > MIN_N_S
    assert pj.default_config(chain).n_s == 2 * p
    assert pj.default_config(chain, n_s=100).n_s == 100  # a setting given is kept
    assert pj.SolverConfig().resolved_n_s(chain) == 2 * p  # also without default_config
    with pytest.raises(pj.ConfigError, match=f"below the {p} regressors"):
        pj.solve(chain, pj.default_config(chain, n_s=p - 1))


def test_a_thirty_hinge_chain_solves_with_the_defaults(tmp_path):
    chain = _chain(tmp_path)
    result = pj.solve(chain, pj.SolverConfig(max_iterations=2))  # every other setting at its default
    assert result.engine == "native" and result.config["n_s"] == 6 * LINKS
    assert np.isfinite(result.final_cost) and result.final_cost < result.cost_history[0]
