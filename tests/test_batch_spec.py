"""Campaign specs: validation with the offending key named, expansion, seeds that depend on the
data only, the dotted-settings adapter, and the χ² consistency test."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from svains.batch import load_spec, parse_spec
from svains.batch.consistency import chi2_average_bounds, nees_test
from svains.batch.settings import run_options_from_settings
from svains.batch.spec import derive_seed, nest
from svains.errors import ConfigError
from svains.navigation.options import VisionOptions

BASE: dict[str, Any] = {
    "scenarios": {"v": {"duration_s": 10, "camera.rate_hz": 5, "camera.render_images": False}},
    "methods": ["ins", "3d"],
    "seeds": [0, 1],
    "settings": {"init.mode": "groundtruth"},
}


def _spec(**changes: Any) -> dict[str, Any]:
    return {**BASE, **changes}


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"metods": ["ins"]}, "unknown campaign spec key 'metods'"),
        ({"methods": ["ins", "ukf"]}, "unknown method 'ukf'"),
        ({"settings": {"vision.pixel_noise_scal": 1.0}}, "pixel_noise_scal"),
        ({"settings": {"fusion.use_gsp": False}}, "unknown setting 'fusion.use_gsp'"),
        ({"settings": {"fusion.use_gps": "no"}}, "'fusion.use_gps' must be a bool"),
        ({"settings": {"init.mode": "gt"}}, "'init.mode' must be one of static, gps"),
        ({"configs": {"a": {"filter.alfa": 1.0}}}, "config 'a': unknown setting 'filter.alfa'"),
        ({"scenarios": {"v": {"camera.rte_hz": 5}}}, "unknown simulator config key 'camera.rte_"),
        ({"scenarios": {"v": {"seed": 3}}}, "'seed' comes from the spec's seeds"),
        ({"replicates": 3}, "either 'seeds'"),
        ({"seeds": [1, 1]}, "lists a seed twice"),
        ({"datasets": {"d": {"path": "x", "rate": 5}}}, "dataset 'd': unknown key 'rate'"),
        ({"datasets": {"d": {"path": ".", "calib": "nope.yaml"}}},
         "dataset 'd': calib"),
        ({"datasets": {"d": {"path": ".", "topics": "lefty=/a"}}},
         "dataset 'd': topics name a bag's topics"),
        ({"scenarios": {"bad name": {}}}, "name 'bad name' must match"),
    ],
)  # fmt: skip
def test_a_bad_spec_is_refused_with_the_offending_key_named(
    changes: dict[str, Any], message: str
) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_spec(_spec(**changes))


def test_a_data_set_path_that_is_not_a_folder_is_refused_on_load(tmp_path: Path) -> None:
    """Every run of it failed one by one before, after the others' work (a user's probe)."""
    with pytest.raises(ConfigError, match=r"dataset 'd': path .*/nonexistent_ds is not a "
                       r"folder or a bag"):  # fmt: skip
        parse_spec(_spec(datasets={"d": {"path": "nonexistent_ds"}}), tmp_path)


def test_metrics_no_finished_run_reports_are_named_with_the_closest_keys() -> None:
    from svains.batch.summary import unknown_metrics

    rows = [{"status": "ok", "ate_m": 0.1, "nees_mean": 9.0, "method": "3d"},
            {"status": "failed", "ate": None}]
    assert unknown_metrics(["ate", "nees_mean", "nees"], rows) == {
        "ate": ["ate_m"], "nees": ["nees_mean"]}
    assert unknown_metrics(["ate"], rows[1:]) == {}  # nothing finished: nothing to judge


def test_a_campaign_with_a_failed_run_exits_1_naming_the_count(tmp_path: Path) -> None:
    """``svains batch`` exited 0 with every run failed: a script or CI could not tell."""
    from typer.testing import CliRunner

    from svains.cli.main import app

    (tmp_path / "empty").mkdir()
    spec = tmp_path / "spec.yaml"
    spec.write_text("name: x\ndatasets:\n  e: {path: empty}\nmethods: [ins]\n")
    res = CliRunner().invoke(app, ["batch", str(spec), "--out", str(tmp_path / "c"),
                                   "--sequential", "--no-figures"])  # fmt: skip
    assert res.exit_code == 1, res.output
    assert f"error: 1 of 1 runs failed (their errors: {tmp_path / 'c'}/summary.md)" in res.stderr
    assert "unrecognised data set" in (tmp_path / "c" / "summary.md").read_text()


def test_a_spec_file_that_is_not_a_mapping_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "s.yaml"
    p.write_text("- just\n- a list\n")
    with pytest.raises(ConfigError, match=r"s\.yaml: campaign spec must be a mapping"):
        load_spec(p)
    p.write_text("methods: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(ConfigError, match="cannot read campaign spec"):
        load_spec(p)  # safe_load: a spec never names code to run


def test_the_campaign_is_the_product_of_sources_seeds_configs_and_methods(tmp_path: Path) -> None:
    (tmp_path / "data" / "x").mkdir(parents=True)
    spec = parse_spec(_spec(
        configs={"a": {}, "b": {"vision.pixel_noise_scale": 1.0}},
        datasets={"real": {"path": "data/x"}, "synth": {"path": "/", "synthetic_features_hz": 5}},
    ), tmp_path)  # fmt: skip
    tasks = spec.tasks()
    # scenario and synthetic data set: 2 seeds x 2 configs x 2 methods; real: 2 configs x 2
    assert len(tasks) == 8 + 8 + 4
    assert len({t.task_id for t in tasks}) == len(tasks)
    real = [t for t in tasks if t.source == "real"]
    assert {t.seed for t in real} == {None}
    assert real[0].data["path"] == str(tmp_path / "data" / "x")
    b = next(t for t in tasks if t.config == "b")
    assert b.settings == {"init.mode": "groundtruth", "vision.pixel_noise_scale": 1.0}


def test_replicate_seeds_depend_on_the_data_not_on_the_method_config_or_position() -> None:
    a = parse_spec(_spec(seeds=None, replicates=3))
    b = parse_spec(_spec(seeds=None, replicates=5, methods=["3d", "lc", "ins"],
                         configs={"x": {"fusion.use_gps": False}, "default": {}}))  # fmt: skip
    seeds_a = [t.seed for t in a.tasks() if t.method == "ins"]
    seeds_b = [t.seed for t in b.tasks() if t.method == "ins" and t.config == "default"]
    assert seeds_b[:3] == seeds_a and len(set(seeds_b)) == 5
    # Every method and config of a replicate flies the same simulated flight.
    assert {t.seed for t in b.tasks() if t.replicate == 1} == {seeds_a[1]}
    # A pinned value: the derivation is SHA-256, stable across machines and Python versions.
    assert derive_seed("v", {"duration_s": 10}, 0) == derive_seed("v", {"duration_s": 10}, 0)
    assert derive_seed("v", {"duration_s": 10}, 0) != derive_seed("v", {"duration_s": 11}, 0)
    # sha256(b'{"data":{},"replicate":0,"source":"v"}'), first 31 bits
    assert derive_seed("v", {}, 0) == 1816015107
    # A task's id (its folder) changes with any of its parameters.
    ids_a = {t.task_id for t in a.tasks()}
    c = parse_spec(_spec(seeds=None, replicates=3, settings={"init.mode": "static"}))
    assert ids_a.isdisjoint({t.task_id for t in c.tasks()})


def test_dotted_and_nested_keys_are_the_same_settings() -> None:
    assert nest({"camera.rate_hz": 5, "camera": {"enabled": True}}, "x") == {
        "camera": {"rate_hz": 5, "enabled": True}
    }
    with pytest.raises(ConfigError, match=r"'camera\.rate_hz' is set twice"):
        nest({"camera.rate_hz": 5, "camera": {"rate_hz": 4}}, "x")
    a = parse_spec(_spec(settings={"vision": {"pixel_noise_scale": 1.0}, "init.mode": "gps"}))
    assert a.configs["default"] == {"vision.pixel_noise_scale": 1.0, "init.mode": "gps"}


def test_settings_map_onto_the_run_options() -> None:
    opts = run_options_from_settings({
        "model": "paper", "fusion.use_gps": False, "fusion.max_mag_rate_hz": 5,
        "init.mode": "groundtruth", "filter.max_predict_steps": 1, "noise.white_scale": 2,
        "output.period_s": 0.2, "replay.duration_s": 30, "vision.pixel_noise_scale": 1.0,
    })  # fmt: skip
    assert opts.model == "paper" and opts.use_gps is False and opts.max_mag_rate_hz == 5.0
    assert opts.init.mode == "groundtruth" and opts.filter.max_predict_steps == 1
    assert opts.noise.white_scale == 2.0 and isinstance(opts.noise.white_scale, float)
    assert opts.output_period_s == 0.2 and opts.duration_s == 30.0
    assert opts.vision.pixel_noise_scale == 1.0 and opts.vision == VisionOptions(
        pixel_noise_scale=1.0)
    assert opts.use_mag is True  # untouched fields keep their defaults
    faults = run_options_from_settings({"faults.bias_test_probability": 0.95,
                                        "zupt.enabled": False, "smoother.enabled": True})
    assert faults.faults.bias_test_probability == 0.95 and faults.zupt.enabled is False
    assert faults.smoother.enabled is True
    with pytest.raises(ConfigError, match=r"setting 'faults\.inflate_factor' must be a float"):
        run_options_from_settings({"faults.inflate_factor": "big"})


def test_chi2_bounds_of_an_average_match_the_textbook_values() -> None:
    # Bar-Shalom et al. (2001), example 5.4.2: N = 50 runs, n = 2: [1.5, 2.6].
    lo, hi = chi2_average_bounds(50, dof=2)
    assert lo == pytest.approx(1.5, abs=0.02) and hi == pytest.approx(2.6, abs=0.02)
    lo, hi = chi2_average_bounds(100)
    assert lo < 9.0 < hi and hi - lo == pytest.approx(1.66, abs=0.01)


def test_the_nees_test_accepts_consistent_runs_and_flags_an_overconfident_filter() -> None:
    rng = np.random.default_rng(7)
    t_ns = np.arange(200, dtype=np.int64) * 100_000_000
    runs = [(t_ns, rng.chisquare(9, len(t_ns))) for _ in range(50)]
    ok = nees_test(runs)
    assert ok is not None and ok.n_runs == 50 and len(ok.t_ns) == 200
    assert ok.verdict == "inside" and 0.88 <= ok.fraction_inside <= 1.0
    bad = nees_test([(t, 2.0 * v) for t, v in runs])
    assert bad is not None and bad.verdict.startswith("above by") and bad.fraction_inside < 0.05
    # Only the steps every run has are tested.
    short = nees_test([*runs[:3], (t_ns[50:], runs[3][1][50:])])
    assert short is not None and len(short.t_ns) == 150 and short.n_runs == 4


def test_svains_batch_names_a_bad_key_and_exits_1(tmp_path: Path) -> None:
    import yaml
    from typer.testing import CliRunner

    from svains.cli.main import app

    p = tmp_path / "spec.yaml"
    p.write_text(yaml.safe_dump(_spec(settings={"vision.rotaton": "imu"})))
    res = CliRunner().invoke(app, ["batch", str(p), "--out", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert "rotaton" in res.output and not (tmp_path / "o").exists()


def test_a_bag_with_its_kalibr_files_and_topics_runs_in_a_campaign(
    euroc_micro: Path, tmp_path: Path
) -> None:
    """A campaign's data set may be a bag with its Kalibr files and topics, as `svains run`
    takes them (`path` had to be a folder; no calibration or topic could be given: a user's
    probe); a spec without them keeps its task ids."""
    from typer.testing import CliRunner

    from _kalibr_files import write_euroc_kalibr
    from svains.cli.main import app
    from svains.datasets import load_dataset
    from svains.datasets.rosbag_writer import write_bag

    ds = load_dataset(euroc_micro)
    write_euroc_kalibr(ds, tmp_path / "kalibr")
    write_bag(ds, tmp_path / "odd.bag", "ros1", topics={"left": "/a", "right": "/b"},
              t_end_ns=int(ds.left.t_ns[0]) + 1_000_000_000)  # fmt: skip
    plain = parse_spec(_spec(datasets={"e": {"path": str(euroc_micro)}}), tmp_path)
    assert plain.datasets["e"] == {"path": str(euroc_micro), "synthetic_features_hz": None}
    # topics: one spelling whatever the order or form (the task id must not hang on it); on a
    # folder, or a role left empty, refused when the spec loads, not run by run
    forms = [{"right": "/b", "left": "/a"}, {"left": "/a", "right": "/b"}, ["left=/a", "right=/b"],
             "right=/b,left=/a"]  # fmt: skip
    spelled = {parse_spec(_spec(datasets={"b": {"path": "odd.bag", "topics": f}}),
                          tmp_path).datasets["b"]["topics"] for f in forms}  # fmt: skip
    assert spelled == {"left=/a,right=/b"}
    for data, message in (
        ({"path": str(euroc_micro), "topics": {"left": "/a"}}, "topics name a bag's topics"),
        ({"path": "odd.bag", "topics": {"left": None}}, "the left topic is empty"),
        *(({"path": "odd.bag", "topics": empty}, "dataset 'b': topics is empty")
          for empty in ("", "  ", {}, [])),
        ({"path": "odd.bag", "topics": {"left": "/a,right=/c"}},
         "the left topic '/a,right=/c' is not one topic"),
    ):
        with pytest.raises(ConfigError, match=re.escape(message)):
            parse_spec(_spec(datasets={"b": data}), tmp_path)
    spec = tmp_path / "spec.yaml"
    spec.write_text("name: bag\ndatasets:\n  b: {path: odd.bag, calib: kalibr/camchain-imucam"
                    ".yaml, imu_calib: kalibr/imu.yaml, topics: {left: /a, right: /b}}\n"
                    "methods: [3d]\nsettings: {init.mode: groundtruth, replay.duration_s: 0.8, "
                    "fusion.use_gps: false, fusion.use_mag: false}\n")  # fmt: skip
    res = CliRunner().invoke(app, ["batch", str(spec), "--out", str(tmp_path / "c"),
                                   "--sequential", "--no-figures"])  # fmt: skip
    assert res.exit_code == 0, res.output + res.stderr
