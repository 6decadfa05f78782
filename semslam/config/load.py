"""Loading the config tree: presets are YAML files that set fields of it.

``load_config("orb", overrides=["slam.loop_closing=false"])`` reads
``semslam/presets/orb.yaml`` (or a YAML path), applies ``--set`` overrides and checks
every key, so a typo in a preset is an error instead of a silently ignored setting.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import yaml

from semslam.config.checks import check_values
from semslam.config.schema import SENSORS, SystemConfig
from semslam.errors import ConfigError

PRESET_DIR = Path(__file__).parent.parent / "presets"


def available_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def _apply(obj: Any, values: dict[str, Any], where: str) -> None:
    """Set dataclass fields from a nested dict, refusing unknown keys and wrong types."""
    fields = {f.name: f for f in dataclasses.fields(obj)}
    for key, value in values.items():
        if key not in fields:
            raise ConfigError(f"{where}: unknown key {key!r} (known: {', '.join(sorted(fields))})")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"{where}.{key}: expected a mapping")
            _apply(current, value, f"{where}.{key}")
            continue
        setattr(obj, key, _coerce(value, current, f"{where}.{key}"))


def _coerce(value: Any, current: Any, where: str) -> Any:
    if isinstance(current, bool):
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected true/false, got {value!r}")
    if isinstance(current, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if isinstance(current, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise ConfigError(f"{where}: expected a number, got {value!r}")
    if isinstance(current, str):
        if isinstance(value, str):
            return value
        raise ConfigError(f"{where}: expected a string, got {value!r}")
    if isinstance(current, list):
        if isinstance(value, list):
            return value
        raise ConfigError(f"{where}: expected a list, got {value!r}")
    return value


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    return data


def parse_override(text: str) -> tuple[list[str], Any]:
    """``section.key=value`` with the value parsed as YAML (numbers, booleans, lists)."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    key, raw = text.split("=", 1)
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        value = raw
    return key.strip().split("."), value


def load_config(preset: str | Path = "default", overrides: list[str] | None = None) -> SystemConfig:
    """Config of a named preset (or a YAML file) with ``--set`` overrides applied."""
    path = Path(preset)
    if path.suffix not in (".yaml", ".yml"):
        path = PRESET_DIR / f"{preset}.yaml"
        if not path.is_file():
            raise ConfigError(f"unknown preset {preset!r} (available: {', '.join(available_presets())})")
    elif not path.is_file():
        raise ConfigError(f"{path}: preset file not found")
    data = _read_yaml(path)
    base = data.pop("inherit", None)
    cfg = load_config(base) if base else SystemConfig()
    _apply(cfg, data, path.stem)
    cfg.preset = data.get("preset", path.stem)
    _apply_overrides(cfg, overrides)
    return cfg


def _apply_overrides(cfg: SystemConfig, overrides: list[str] | None) -> None:
    """``--set section.key=value`` overrides, then the whole-config checks."""
    for text in overrides or []:
        keys, value = parse_override(text)
        nested: dict[str, Any] = {keys[-1]: value}
        for k in reversed(keys[:-1]):
            nested = {k: nested}
        _apply(cfg, nested, "--set")
    _check(cfg)


def _check(cfg: SystemConfig) -> None:
    """Values no component can use, refused once at load time with the key that holds them:
    the sections' own checks (their messages say more), then every field against its rule
    (config/checks.py)."""
    if cfg.sensor not in SENSORS:
        raise ConfigError(f"sensor: unknown sensor {cfg.sensor!r} (known: {', '.join(SENSORS)})")
    cfg.features.check()
    cfg.semantics.check()
    check_values(cfg)


def config_to_dict(cfg: SystemConfig) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


def config_from_dict(data: dict[str, Any], where: str, overrides: list[str] | None = None) -> SystemConfig:
    """The config a run wrote (``config.json``), checked like a preset, with ``--set`` overrides."""
    data = dict(data)
    preset = data.pop("preset", "custom")
    cfg = SystemConfig()
    _apply(cfg, data, where)
    cfg.preset = preset
    _apply_overrides(cfg, overrides)
    return cfg
