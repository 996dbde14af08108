"""The package's environment variables: one parsing rule per kind of value
(``podilqr_jax/environment.py``), and the readers that use them."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from podilqr_jax import environment

NAME = "PODILQR_TEST_SWITCH"


@pytest.mark.parametrize("text", ["1", "on", "ON", " true ", "yes"])
def test_a_switch_is_on(monkeypatch, text):
    monkeypatch.setenv(NAME, text)
    assert environment.switch(NAME, False) is True
    assert environment.choice(NAME, "auto", {"auto": "auto"}) == "on"


@pytest.mark.parametrize("text", ["0", "off", "False", "no"])
def test_a_switch_is_off(monkeypatch, text):
    monkeypatch.setenv(NAME, text)
    assert environment.switch(NAME, True) is False
    assert environment.choice(NAME, "auto", {"auto": "auto"}) == "off"


def test_unset_or_empty_is_the_default(monkeypatch):
    monkeypatch.delenv(NAME, raising=False)
    assert environment.switch(NAME, True) is True and environment.switch(NAME, False) is False
    monkeypatch.setenv(NAME, "  ")
    assert environment.choice(NAME, "auto", {"auto": "auto"}) == "auto"
    assert environment.folder(NAME) is None


def test_named_values_and_folders(monkeypatch):
    monkeypatch.setenv(NAME, "RO")
    assert environment.choice(NAME, "on", {"read": "read", "ro": "read"}) == "read"
    monkeypatch.setenv(NAME, "~/somewhere")
    assert environment.folder(NAME) == os.path.join(os.path.expanduser("~"), "somewhere")


def test_a_value_outside_the_rule_keeps_the_default_and_says_so(monkeypatch):
    monkeypatch.setattr(environment, "_warned", set())
    monkeypatch.setenv(NAME, "maybe")
    with pytest.warns(UserWarning, match=r"PODILQR_TEST_SWITCH='maybe' is not one of 1/on, 0/off; using off"):
        assert environment.switch(NAME, False) is False
    monkeypatch.setenv(NAME, "7x")
    with pytest.warns(UserWarning, match=r"not one of 1/on, 0/off, auto; using auto"):
        assert environment.choice(NAME, "auto", {"auto": "auto"}) == "auto"


def test_float64_is_switched_off_by_any_off_spelling():
    """PODILQR_X64 reads by the switch rule: `off` turns float64 off as `0` does."""
    code = "import podilqr_jax, jax, jax.numpy as jnp; import podilqr_jax.sim; print(jnp.zeros(1).dtype)"
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    dtypes = [
        subprocess.run(
            [sys.executable, "-c", code], env=env | {"PODILQR_X64": value}, capture_output=True, text=True
        ).stdout.strip()
        for value in ("off", "1")
    ]
    assert dtypes == ["float32", "float64"]
