"""The one way every study is sized and configured (podilqr_jax/studies/settings.py)."""

from __future__ import annotations

import argparse

import pytest

import podilqr_jax as pj
from podilqr_jax.studies.bench import BenchSettings
from podilqr_jax.studies.evaluate import EvaluateSettings
from podilqr_jax.studies.reproduce import ReproduceSettings
from podilqr_jax.studies.settings import Sized, add_size_flags, check_writable, parse_names, size_of

STUDIES = (ReproduceSettings, EvaluateSettings, BenchSettings)


@pytest.mark.parametrize("cls", STUDIES, ids=lambda c: c.__name__)
def test_every_study_has_three_sizes_and_one_way_to_change_them(cls):
    assert issubclass(cls, Sized)
    default, quick, tiny = (cls.sized(size) for size in ("default", "quick", "tiny"))
    assert default == cls() and quick == cls.quick() and tiny == cls.tiny()
    assert len({repr(default), repr(quick), repr(tiny)}) == 3  # three different sizes, not aliases
    some_field = next(iter(cls.__dataclass_fields__))
    assert quick.changed(**{some_field: None}) == quick  # an option left out keeps the size's value
    assert isinstance(default.as_dict(), dict)
    with pytest.raises(pj.ConfigError, match="one of default, quick, tiny; got 'huge'"):
        cls.sized("huge")


def test_size_flags_are_exclusive_and_pick_the_size():
    parser = argparse.ArgumentParser()
    add_size_flags(parser, quick="q", tiny="t")
    assert [size_of(parser.parse_args(a)) for a in ([], ["--quick"], ["--tiny"])] == ["default", "quick", "tiny"]
    with pytest.raises(SystemExit):
        parser.parse_args(["--quick", "--tiny"])


def test_parse_names_says_what_it_takes():
    assert parse_names(" a, b ,", ("a", "b", "c"), "--x") == ("a", "b")
    with pytest.raises(pj.ConfigError, match=r"--x takes a comma-separated subset of a, b; got 'a,z' \(unknown: z\)"):
        parse_names("a,z", ("a", "b"), "--x")
    with pytest.raises(pj.ConfigError, match=r"got ' , ' \(none given\)"):
        parse_names(" , ", ("a",), "--x")


def test_reproduce_settings_are_checked_before_anything_runs():
    with pytest.raises(pj.ConfigError, match="`seeds` must be an integer >= 1; got 0"):
        ReproduceSettings.tiny().changed(seeds=0).validate()
    with pytest.raises(pj.ConfigError, match="`systems` is a non-empty subset of pendulum, cartpole"):
        ReproduceSettings(systems=("rocket",)).validate()


def test_check_writable_refuses_a_file_in_the_way(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(pj.ConfigError, match="a file of that name"):
        check_writable(str(blocker / "out" / "summary.json"))
    check_writable(str(tmp_path / "new" / "summary.json"))
    assert (tmp_path / "new").is_dir()
