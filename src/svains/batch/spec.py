"""Campaign spec (YAML, data only) and its expansion into tasks, one per run.

A spec names data sources (simulator ``scenarios`` and/or real ``datasets``), ``methods``, seeds
(``seeds``: simulator seeds used as given, or ``replicates``: that many seeds derived by hashing)
and run ``settings`` (dotted keys, see :mod:`svains.batch.settings`) with named ``configs`` of
extra settings. The campaign is their product. Every key is checked when the spec is loaded;
an unknown key raises :class:`ConfigError` naming it. Nothing in a spec is ever executed.

A task's seed is a function of its data source and replicate only (never of the method, the
config or the task's position), so every method and config of a campaign sees the same
simulated flights: paired comparisons, and one run's result is the same whatever else is in
the campaign.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from svains.batch.settings import run_options_from_settings
from svains.errors import ConfigError
from svains.evaluation.compare import METHODS
from svains.sim.config import SimConfig
from svains.yaml_io import load_yaml

SourceKind = Literal["scenario", "dataset"]

_SPEC_KEYS = ("name", "description", "scenarios", "datasets", "methods", "seeds", "replicates",
              "settings", "configs", "metrics")  # fmt: skip
_DATASET_KEYS = ("path", "synthetic_features_hz", "calib", "imu_calib", "topics")
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")
# Columns of summary.md when the spec does not list its own ``metrics``.
DEFAULT_METRICS: tuple[str, ...] = (
    "ate_m", "position_rmse_m", "velocity_rmse_mps", "attitude_rmse_deg", "nees_mean",
    "final_error_pct_of_path",
)  # fmt: skip


@dataclass(frozen=True)
class Task:
    """One run: ``method`` with the dotted run ``settings`` of config ``config`` on data source
    ``source``, a simulator scenario (``data``: its nested ``SimConfig`` overrides, simulated
    with ``seed``) or a data set (``data``: ``path``, absolute, and ``synthetic_features_hz``,
    features simulated with ``seed``; ``calib``, ``imu_calib``, ``topics`` when given). Plain
    data only: it travels to Dask workers."""

    source: str
    kind: SourceKind
    data: dict[str, Any]
    method: str
    config: str
    settings: dict[str, Any]
    seed: int | None
    replicate: int | None = None

    def params(self) -> dict[str, Any]:
        """Every parameter of the run (what its result depends on), JSON-able."""
        return {"source": self.source, "kind": self.kind, "data": self.data,
                "method": self.method, "config": self.config, "settings": self.settings,
                "seed": self.seed}  # fmt: skip

    def data_key(self) -> str:
        """Identifies the task's data (source, data parameters and seed): tasks with equal keys
        run on identical data, so their data can be made once."""
        return _canonical({"source": self.source, "kind": self.kind, "data": self.data,
                           "seed": self.seed})  # fmt: skip

    @property
    def task_id(self) -> str:
        """Readable and unique: ``source-config-method-sSEED-HASH8``, the hash over
        :meth:`params`, so a changed spec never reuses an old run's results."""
        digest = hashlib.sha256(_canonical(self.params()).encode()).hexdigest()[:8]
        seed = "" if self.seed is None else f"-s{self.seed}"
        return f"{self.source}-{self.config}-{self.method}{seed}-{digest}"


@dataclass(frozen=True)
class CampaignSpec:
    """A validated spec (see the module docstring); ``tasks()`` expands it."""

    name: str
    scenarios: dict[str, dict[str, Any]]
    datasets: dict[str, dict[str, Any]]
    methods: tuple[str, ...]
    seeds: tuple[int, ...] | None
    replicates: int | None
    configs: dict[str, dict[str, Any]]
    metrics: tuple[str, ...] = DEFAULT_METRICS
    description: str = ""
    raw: dict[str, Any] = field(default_factory=dict, repr=False)

    def _seeds(self, source: str, data: dict[str, Any]) -> list[tuple[int, int | None]]:
        if self.replicates is None:
            return [(s, None) for s in self.seeds or (0,)]
        return [(derive_seed(source, data, k), k) for k in range(self.replicates)]

    def tasks(self) -> list[Task]:
        """The campaign: sources x seeds x configs x methods (a data set without synthetic
        features has one run per config and method, seedless)."""
        out: list[Task] = []
        sources: list[tuple[str, SourceKind, dict[str, Any]]] = [
            *((n, "scenario", d) for n, d in self.scenarios.items()),
            *((n, "dataset", d) for n, d in self.datasets.items()),
        ]
        for name, kind, data in sources:
            seeded = kind == "scenario" or data.get("synthetic_features_hz") is not None
            seeds = self._seeds(name, data) if seeded else [(None, None)]
            for seed, rep in seeds:
                for config, settings in self.configs.items():
                    for method in self.methods:
                        out.append(Task(name, kind, data, method, config, settings, seed, rep))
        return out


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def derive_seed(source: str, data: Mapping[str, Any], replicate: int) -> int:
    """Seed of replicate ``replicate`` of a data source: the first 31 bits of the SHA-256 of the
    source's name, its parameters and the replicate number (stable across Python versions and
    machines, unlike ``hash``)."""
    key = _canonical({"source": source, "data": dict(data), "replicate": replicate})
    return int.from_bytes(hashlib.sha256(key.encode()).digest()[:4], "big") & 0x7FFFFFFF


def nest(dotted: Mapping[str, Any], where: str) -> dict[str, Any]:
    """``{"a.b": 1, "a": {"c": 2}}`` -> ``{"a": {"b": 1, "c": 2}}``; a key set twice raises."""
    out: dict[str, Any] = {}
    for key, value in dotted.items():
        parts = str(key).split(".")
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{where}: '{key}' sets a key inside a value")
        if isinstance(value, Mapping):
            value = nest(value, f"{where}: {key}")
        leaf = parts[-1]
        if leaf in node and isinstance(node[leaf], dict) and isinstance(value, dict):
            clash = sorted(set(node[leaf]) & set(value))
            if clash:
                raise ConfigError(f"{where}: '{key}.{clash[0]}' is set twice")
            node[leaf].update(value)
        elif leaf in node:
            raise ConfigError(f"{where}: '{key}' is set twice")
        else:
            node[leaf] = value
    return out


def flatten(nested: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Inverse of :func:`nest`: nested mappings -> dotted keys."""
    out: dict[str, Any] = {}
    for key, value in nested.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def _mapping(value: Any, where: str) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where} must be a mapping, got {type(value).__name__}")
    return dict(value)


def _named(value: Any, where: str) -> dict[str, Any]:
    out = _mapping(value, where)
    for name in out:
        if not isinstance(name, str) or not _NAME.match(name):
            raise ConfigError(f"{where}: name {name!r} must match {_NAME.pattern}")
    return out


def _scenario(name: str, value: Any) -> dict[str, Any]:
    data = nest(_mapping(value, f"scenario '{name}'"), f"scenario '{name}'")
    if "seed" in data:
        raise ConfigError(f"scenario '{name}': 'seed' comes from the spec's seeds/replicates")
    try:
        SimConfig.from_dict(data).validate()
    except (ConfigError, TypeError) as exc:
        raise ConfigError(f"scenario '{name}': {exc}") from exc
    return data


def _dataset(name: str, value: Any, base: Path) -> dict[str, Any]:
    data = _mapping(value, f"dataset '{name}'")
    unknown = sorted(set(data) - set(_DATASET_KEYS))
    if unknown:
        raise ConfigError(f"dataset '{name}': unknown key '{unknown[0]}' "
                          f"(known: {', '.join(_DATASET_KEYS)})")  # fmt: skip
    if "path" not in data:
        raise ConfigError(f"dataset '{name}': needs a 'path'")
    from svains.datasets.rosbag import is_bag, parse_topic_roles, topic_roles_text

    # Resolved on the submitting machine: workers must see the data set at this same path.
    path = _resolved(data["path"], base)
    if not (path.is_dir() or is_bag(path)):  # every run would fail, one by one, after the rest
        raise ConfigError(f"dataset '{name}': path {path} is not a folder or a bag")
    hz = data.get("synthetic_features_hz")
    if hz is not None and not (isinstance(hz, int | float) and hz > 0):
        raise ConfigError(f"dataset '{name}': synthetic_features_hz must be positive, got {hz!r}")
    out: dict[str, Any] = {"path": str(path), "synthetic_features_hz": hz}
    # Kalibr files and bag topics (as svains run's --calib, --imu-calib, --topic), kept only
    # when given: the task ids of specs without them stay as they were
    for key in ("calib", "imu_calib"):
        if data.get(key) is not None:
            f = _resolved(data[key], base)
            if not f.is_file():
                raise ConfigError(f"dataset '{name}': {key} {f} is not a file")
            out[key] = str(f)
    topics = data.get("topics")
    if topics is not None:
        if not is_bag(path):  # every run would fail on it, one by one
            raise ConfigError(f"dataset '{name}': topics name a bag's topics; {path} is not a "
                              "bag")  # fmt: skip
        if isinstance(topics, dict):
            bad = [k for k, v in topics.items() if not isinstance(v, str) or not v.strip()]
            if bad:
                raise ConfigError(f"dataset '{name}': topics: the {bad[0]} topic is empty")
            # a topic with "," or "=" would be read as more roles ({left: "/a,right=/c"})
            odd = [k for k, v in topics.items() if "," in v or "=" in v]
            if odd:
                raise ConfigError(f"dataset '{name}': topics: the {odd[0]} topic "
                                  f"{topics[odd[0]]!r} is not one topic")  # fmt: skip
            topics = ",".join(f"{k}={v}" for k, v in topics.items())
        elif isinstance(topics, list):  # as --topic given several times
            topics = ",".join(str(t) for t in topics)
        try:
            roles = parse_topic_roles(str(topics))
        except ConfigError as exc:
            raise ConfigError(f"dataset '{name}': {exc}") from None
        if not roles:  # an empty key would change the task ids and choose nothing
            raise ConfigError(f"dataset '{name}': topics is empty (leave the key out to let the "
                              "bag's topics be found by type)")  # fmt: skip
        # one spelling per choice: the task ids do not hang on the order
        out["topics"] = topic_roles_text(roles)
    return out


def _resolved(value: Any, base: Path) -> Path:
    """A spec's path: ``~`` expanded, relative ones from the spec's folder."""
    path = Path(str(value)).expanduser()
    return path if path.is_absolute() else (base / path).resolve()


def _seeds(raw: dict[str, Any]) -> tuple[tuple[int, ...] | None, int | None]:
    seeds, reps = raw.get("seeds"), raw.get("replicates")
    if seeds is not None and reps is not None:
        raise ConfigError("give either 'seeds' (a list) or 'replicates' (a count), not both")
    if seeds is not None and not (
        isinstance(seeds, list) and seeds and all(type(s) is int and s >= 0 for s in seeds)
    ):
        raise ConfigError(f"'seeds' must be a non-empty list of integers >= 0, got {seeds!r}")
    if seeds is not None and len(set(seeds)) != len(seeds):
        raise ConfigError(f"'seeds' lists a seed twice: {seeds!r}")
    if reps is not None and not (type(reps) is int and reps >= 1):
        raise ConfigError(f"'replicates' must be an integer >= 1, got {reps!r}")
    return (tuple(seeds) if seeds is not None else None), reps


def parse_spec(raw: Any, base: Path = Path(".")) -> CampaignSpec:
    """Validate a spec mapping; relative data-set paths are taken from ``base``."""
    raw = _mapping(raw, "campaign spec")
    unknown = sorted(set(raw) - set(_SPEC_KEYS))
    if unknown:
        raise ConfigError(f"unknown campaign spec key '{unknown[0]}' "
                          f"(known: {', '.join(_SPEC_KEYS)})")  # fmt: skip
    scenarios = {n: _scenario(n, v) for n, v in _named(raw.get("scenarios"), "scenarios").items()}
    datasets = {n: _dataset(n, v, base) for n, v in _named(raw.get("datasets"), "datasets").items()}
    if not scenarios and not datasets:
        raise ConfigError("a campaign spec needs 'scenarios' and/or 'datasets'")
    overlap = sorted(set(scenarios) & set(datasets))
    if overlap:
        raise ConfigError(f"'{overlap[0]}' names both a scenario and a data set")
    methods = raw.get("methods")
    if not (isinstance(methods, list) and methods):
        raise ConfigError(f"'methods' must be a non-empty list of {', '.join(METHODS)}")
    for m in methods:
        if m not in METHODS:
            raise ConfigError(f"unknown method {m!r} in 'methods' (known: {', '.join(METHODS)})")
    seeds, reps = _seeds(raw)
    common = flatten(nest(_mapping(raw.get("settings"), "settings"), "settings"))
    configs_raw = _named(raw.get("configs"), "configs") or {"default": {}}
    configs: dict[str, dict[str, Any]] = {}
    for name, extra in configs_raw.items():
        where = f"config '{name}'"
        merged = {**common, **flatten(nest(_mapping(extra, where), where))}
        try:
            run_options_from_settings(merged)  # fail now, not on a worker
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        configs[name] = merged
    metrics = raw.get("metrics", list(DEFAULT_METRICS))
    if not (isinstance(metrics, list) and all(isinstance(m, str) for m in metrics)):
        raise ConfigError(f"'metrics' must be a list of report keys, got {metrics!r}")
    return CampaignSpec(
        name=str(raw.get("name", "campaign")), scenarios=scenarios, datasets=datasets,
        methods=tuple(dict.fromkeys(methods)), seeds=seeds, replicates=reps, configs=configs,
        metrics=tuple(metrics), description=str(raw.get("description", "")), raw=raw,
    )  # fmt: skip


def load_spec(path: Path | str) -> CampaignSpec:
    """Read and validate a YAML spec (``yaml_io.load_yaml``: data only, no key twice)."""
    p = Path(path)
    try:
        raw = load_yaml(p.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read campaign spec {p}: {exc}") from exc
    try:
        return parse_spec(raw, p.resolve().parent)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from exc
