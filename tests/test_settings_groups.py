"""The solver's settings in groups (ilqr/config.py): each group a frozen record
that validates itself, every setting also by its flat name (keywords,
attributes, ``replace``, ``default_config``, ``--set``, a task file's
``[solver]`` table), and results and checkpoints recording the flat names."""

from __future__ import annotations

import dataclasses
import os

import pytest

import podilqr_jax as pj
from podilqr_jax.ilqr.checkpoint import fingerprint
from podilqr_jax.ilqr.config import GROUPS, SETTINGS
from podilqr_jax.task.taskfile import load_task

GROUP_OF = {
    "max_iterations": "ilqr",
    "mu_max": "ilqr",
    "seed": "ilqr",
    "n_s": "identification",
    "sigma": "identification",
    "estimator": "identification",
    "variant": "noise",
    "n_avg": "noise",
    "reidentify": "recovery",
    "engine": "execution",
    "memory_budget_mb": "execution",
    "jacobian": "reference",
}


def test_every_setting_sits_in_one_group_and_keeps_its_flat_name():
    names = [f.name for cls in GROUPS.values() for f in dataclasses.fields(cls)]
    assert len(names) == len(set(names)) == len(SETTINGS) == 39
    assert {name: SETTINGS[name] for name in GROUP_OF} == GROUP_OF
    cfg = pj.SolverConfig(n_s=80, variant="averaged", jacobian="differences")
    assert cfg.identification == pj.IdentificationSettings(n_s=80)
    assert cfg.noise == pj.NoiseSettings(variant="averaged")
    assert cfg.reference == pj.ReferenceSettings(jacobian="differences")
    assert (cfg.n_s, cfg.variant, cfg.jacobian, cfg.sigma) == (80, "averaged", "differences", 1e-4)
    # A group given whole, a flat setting on top of it (the setting wins), and replace with either.
    grouped = pj.SolverConfig(
        identification=pj.IdentificationSettings(n_s=80, sigma=1e-3), noise={"variant": "averaged"}, sigma=1e-5
    )
    assert (grouped.n_s, grouped.sigma, grouped.variant) == (80, 1e-5, "averaged")
    assert cfg.replace(sigma=1e-3).identification == pj.IdentificationSettings(n_s=80, sigma=1e-3)
    assert cfg.replace(ilqr=pj.ILQRSettings(max_iterations=5)).max_iterations == 5
    assert cfg.replace(ilqr=pj.ILQRSettings(max_iterations=5)).n_s == 80
    assert cfg.flat() == {name: getattr(cfg, name) for name in SETTINGS}
    assert pj.SolverConfig(**cfg.flat()) == cfg and hash(pj.SolverConfig(**cfg.flat())) == hash(cfg)
    with pytest.raises(AttributeError, match="no setting 'sigmaa'"):
        cfg.sigmaa  # noqa: B018 - the attribute read is the test


def test_each_group_validates_itself():
    cases = [
        (pj.ILQRSettings(mu_factor=1.0), "`mu_factor` must be > 1"),
        (pj.ILQRSettings(mu_min=1.0, mu_max=0.5), "`mu_min` \\(1\\) is above `mu_max`"),
        (pj.IdentificationSettings(sigma_scale="metres"), "Unknown `sigma_scale` 'metres'"),
        (pj.IdentificationSettings(n_s=0), "`n_s` must be an integer >= 1"),
        (pj.NoiseSettings(n_avg=4), "`n_avg`=4 only applies to variant='averaged'"),
        (pj.RecoverySettings(reidentify=-1), "`reidentify` must be an integer >= 0"),
        (pj.ExecutionSettings(engine="gpu"), "Unknown `engine` 'gpu'"),
        (pj.ReferenceSettings(jacobian="fd"), "Unknown `jacobian` 'fd'"),
    ]
    for record, message in cases:
        with pytest.raises(pj.ConfigError, match=message):
            record.validate()
        group = next(name for name, cls in GROUPS.items() if isinstance(record, cls))
        with pytest.raises(pj.ConfigError, match=message):  # and the whole configuration refuses it
            pj.SolverConfig(**{group: record}).validate(pj.make_task("pendulum-full"))
    for cls in GROUPS.values():
        cls().validate()  # every default is valid


def test_bad_groups_are_refused_with_what_to_do():
    with pytest.raises(pj.ConfigError, match="`noise` must be a NoiseSettings .* got IdentificationSettings"):
        pj.SolverConfig(noise=pj.IdentificationSettings())
    with pytest.raises(pj.ConfigError, match=r"Unknown setting\(s\) \['n_s'\] in the group `noise`"):
        pj.SolverConfig(noise={"n_s": 80})
    with pytest.raises(pj.ConfigError, match=r"Unknown solver setting\(s\) \['sigmaa'\].*or a group: ilqr"):
        pj.SolverConfig(sigmaa=1.0)


def test_results_and_checkpoints_record_the_flat_settings():
    env = pj.make_task("pendulum-full", horizon=6)
    cfg = pj.default_config(env, identification=pj.IdentificationSettings(sigma=1e-3), max_iterations=2)
    assert cfg.sigma == 1e-3 and cfg.n_s == 40  # the task's default n_s is filled in as before
    config = fingerprint("pod-ilqr", env, env.dims, cfg)["config"]
    assert set(config) <= set(SETTINGS) and config["sigma"] == 1e-3 and "identification" not in config
    result = pj.solve(env, cfg)
    assert set(result.config) == set(SETTINGS) | {"q"} and result.config["sigma"] == 1e-3


def test_a_task_file_takes_flat_settings_and_group_tables(tmp_path):
    model = os.path.join(os.path.dirname(pj.__file__), "task", "models", "pendulum.xml")
    path = tmp_path / "grouped.toml"
    path.write_text(
        f'model = "{model}"\nhorizon = 8\n\n[solver]\nsigma = 1e-5\n\n'
        '[solver.noise]\nvariant = "plain"\n\n[solver.ilqr]\nmax_iterations = 7\n'
    )
    env = load_task(str(path))
    cfg = pj.default_config(env, max_iterations=9)
    assert (cfg.sigma, cfg.variant, cfg.max_iterations) == (1e-5, "plain", 9)
    path.write_text(f'model = "{model}"\nhorizon = 8\n\n[solver.ilqr]\nsigma = 1e-5\n')
    with pytest.raises(pj.ConfigError, match=r"Unknown setting\(s\) \['sigma'\] in the group `ilqr`"):
        pj.default_config(load_task(str(path)))
