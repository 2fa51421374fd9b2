"""The scenario catalog: names, paths, overrides and the seed, validated like any field."""

import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.running import catalog


def test_resolve_takes_a_bundled_name_or_a_path(tmp_path):
    bundled = catalog.resolve("01_intro")
    assert bundled == catalog.bundled_scenarios()["01_intro"] and bundled.is_file()
    own = tmp_path / "mine.yaml"
    own.write_text("end_time: 2\n")
    assert catalog.resolve(str(own)) == own
    assert catalog.load(own).name == "mine" and catalog.load(own).end_time == 2


@pytest.mark.parametrize(
    "name, message",
    [("no_such", "unknown scenario 'no_such' (known: 01_intro, 02_attitude_control"), ("x.yml", "no such")],
)
def test_resolve_refuses_what_is_neither(name, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        catalog.resolve(name)


def test_the_seed_is_applied_last_and_checked_as_the_seed_option():
    assert catalog.load("10_mag_update").seed == 0
    assert catalog.load("10_mag_update", seed=17).seed == 17
    # the seed is applied last: it beats a --set seed=..., and it is checked first, as --seed
    assert catalog.load("10_mag_update", 3, ["seed=5", "end_time=2"]).seed == 3
    with pytest.raises(ConfigError, match=r"^--seed: seeds must lie in \[0, 4294967295\] .*, got -1$"):
        catalog.load("10_mag_update", seed=-1)
    with pytest.raises(ConfigError, match=r"--seed: .* got 4294967296$"):
        catalog.load("10_mag_update", seed=2**32)  # Drake's generator would fly seed 0's noise
    assert catalog.load("10_mag_update", seed=2**32 - 1).seed == 2**32 - 1
    with pytest.raises(ConfigError, match=r"seed: expected int, got 1.5"):
        catalog.load("10_mag_update", seed=1.5)
