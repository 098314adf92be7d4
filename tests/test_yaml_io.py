"""Every YAML a user writes (run configuration, campaign spec, simulator configuration,
sensor.yaml) is read by ``yaml_io.load_yaml``: a key given twice in one mapping is refused with
both lines; PyYAML alone kept the last one without a word (a user's probe: a ``filter:``
section written twice lost the first one's settings)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from svains.batch.spec import load_spec
from svains.errors import CalibrationError, ConfigError
from svains.navigation.config_io import from_yaml, parse_setting
from svains.sim.config import SimConfig
from svains.yaml_io import load_yaml


def test_a_key_twice_is_refused_with_both_lines_and_merges_still_override() -> None:
    with pytest.raises(yaml.YAMLError, match=r"line 3: the key 'filter' is given twice in one "
                       r"mapping \(first on line 1\)"):  # fmt: skip
        load_yaml("filter:\n  alpha: 0.9\nfilter:\n  beta: 1.0\n")
    with pytest.raises(yaml.YAMLError, match=r"line 1: the key 'alpha' is given twice"):
        load_yaml("filter: {alpha: 0.9, alpha: 0.3}\n")
    # the same key in two mappings, and a merge key's override, are not repeats
    assert load_yaml("a: {x: 1}\nb: {x: 2}\n") == {"a": {"x": 1}, "b": {"x": 2}}
    assert load_yaml("base: &b {x: 1, y: 2}\nc:\n  <<: *b\n  x: 3\n")["c"] == {"x": 3, "y": 2}
    with pytest.raises(yaml.YAMLError):  # still the safe loader: no tags that run code
        load_yaml("a: !!python/object/apply:os.system ['true']\n")


@pytest.mark.parametrize(("name", "text", "read", "error"), [
    ("run.yaml", "filter:\n  alpha: 0.9\nfilter:\n  beta: 1.0\n", from_yaml, ConfigError),
    ("spec.yaml", "methods: [ins]\nmethods: [lc]\nscenarios: {v: {}}\n", load_spec, ConfigError),
    ("sim.yaml", "duration_s: 5\nduration_s: 6\n", SimConfig.from_yaml, ConfigError),
])  # fmt: skip
def test_each_user_file_refuses_a_repeated_key_naming_the_file(
    tmp_path: Path, name: str, text: str, read: object, error: type
) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(error, match=rf"{name}.*given twice in one mapping"):
        read(path)  # type: ignore[operator]
    with pytest.raises(ConfigError, match="given twice"):
        parse_setting("vision.lc_min_std={a: 1, a: 2}")


def test_a_sensor_yaml_with_a_repeated_key_is_refused(tmp_path: Path) -> None:
    from svains.datasets._textio import read_sensor_yaml

    path = tmp_path / "sensor.yaml"
    path.write_text("%YAML:1.0\nrate_hz: 200\nrate_hz: 100\n")
    with pytest.raises(CalibrationError, match=r"sensor\.yaml: invalid YAML: line 3: the key "
                       r"'rate_hz' is given twice"):  # fmt: skip
        read_sensor_yaml(path)
