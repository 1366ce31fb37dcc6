"""Config loader: strict keys (nested too), type checks, presets' merge order, the dataclass's own
validation, and dump → load round trips for our own and existing settings classes."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest
from scanreg import RegistrationSettings
from scanreg.config import (
    PRESETS,
    ConfigError,
    config_from_dict,
    dump_config,
    load_config,
    merge_config,
    preset,
    write_config,
)
from scanreg.pipeline.odometry2d import OdometryConfig2D


@dataclass(frozen=True)
class Deskew:
    enabled: bool = True
    reference: Literal["start", "middle", "end"] = "middle"


@dataclass(frozen=True)
class Mapping_:
    voxel_size: float = 1.0
    max_points_per_voxel: int = 20
    deskew: Deskew = field(default_factory=Deskew)


@dataclass(frozen=True)
class Demo:
    name: str = "run"
    max_range: float = 100.0
    min_range: float = 0.0
    voxel_size: float = 1.0
    iterations: int = 10
    rings: tuple[int, ...] = (0, 1)
    window: tuple[float, float] = (0.0, 1.0)
    scale: float | None = None
    mapping: Mapping_ = field(default_factory=Mapping_)

    def __post_init__(self) -> None:
        if self.min_range >= self.max_range:
            raise ValueError(f"min_range: must be < max_range ({self.max_range})")


def test_defaults_and_values() -> None:
    assert config_from_dict(Demo, {}) == Demo()
    cfg = config_from_dict(
        Demo,
        {
            "max_range": 50,  # an int is a fine float
            "rings": [3, 4, 5],
            "window": [0.5, 2],
            "scale": 0.3,
            "mapping": {"voxel_size": 0.5, "deskew": {"reference": "end"}},
        },
    )
    assert cfg.max_range == 50.0 and isinstance(cfg.max_range, float)
    assert cfg.rings == (3, 4, 5) and cfg.window == (0.5, 2.0)
    assert cfg.mapping == Mapping_(voxel_size=0.5, deskew=Deskew(reference="end"))
    assert config_from_dict(Demo, {"scale": None}).scale is None


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (
            {"max_rang": 3.0},
            r"unknown key 'max_rang' in the top level \(valid keys: name, .*\); "
            r"did you mean 'max_range'\?",
        ),
        (
            {"mapping": {"voxelsize": 1.0}},
            r"unknown key 'voxelsize' in \[mapping\] "
            r"\(valid keys: voxel_size, max_points_per_voxel, deskew\)",
        ),
        (
            {"mapping": {"deskew": {"enable": False}}},
            r"unknown key 'enable' in \[mapping\.deskew\] \(valid keys: enabled, reference\)",
        ),
    ],
)
def test_unknown_keys_rejected(data: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        config_from_dict(Demo, data)


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"iterations": 2.5}, r"iterations: expected int, got float 2\.5"),
        ({"iterations": True}, r"iterations: expected int, got bool"),
        ({"max_range": "far"}, r"max_range: expected float, got str 'far'"),
        ({"max_range": False}, r"max_range: expected float, got bool"),
        ({"name": 3}, r"name: expected str"),
        (
            {"mapping": {"deskew": {"enabled": 1}}},
            r"mapping\.deskew\.enabled: expected bool, got int",
        ),
        (
            {"mapping": {"deskew": {"reference": "begin"}}},
            r"reference: expected one of 'start', 'middle', 'end', got 'begin'",
        ),
        ({"rings": [1, "2"]}, r"rings\[1\]: expected int"),
        ({"rings": "0,1"}, r"rings: expected .* \(an array\)"),
        ({"window": [1.0]}, r"window: expected .* \(1 items, expected 2\)"),
        ({"scale": "x"}, r"scale: expected float"),
        ({"mapping": 3}, r"mapping: expected Mapping_, got int 3 \(a table\)"),
        ({"min_range": 200.0}, r"config: the top level: min_range: must be < max_range"),
    ],
)
def test_wrong_types_rejected(data: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        config_from_dict(Demo, data)


@dataclass(frozen=True)
class WithTunedDefault:
    # a plain instance default (frozen, so shared safely) must work as well as a factory
    registration: RegistrationSettings = RegistrationSettings(kernel="huber", max_iterations=7)  # noqa: RUF009
    deskew: Deskew = field(default_factory=lambda: Deskew(reference="end"))


def test_partial_table_keeps_the_fields_default_instance() -> None:
    cfg = config_from_dict(WithTunedDefault, {"registration": {"max_correspondence_distance": 2.0}})
    assert cfg.registration == RegistrationSettings(
        kernel="huber", max_iterations=7, max_correspondence_distance=2.0
    )
    cfg = config_from_dict(WithTunedDefault, {"deskew": {"enabled": False}})
    assert cfg.deskew == Deskew(enabled=False, reference="end")
    assert load_config(WithTunedDefault, dump_config_dict(cfg)) == cfg


def dump_config_dict(cfg: object) -> dict[str, object]:
    from scanreg import config

    out: dict[str, object] = config.tomllib.loads(dump_config(cfg))  # tomli on 3.10
    return out


def test_literal_does_not_confuse_bool_and_int() -> None:
    @dataclass(frozen=True)
    class L:
        mode: Literal[1, 2] = 1

    with pytest.raises(ConfigError, match="expected one of 1, 2, got True"):
        config_from_dict(L, {"mode": True})


def test_toml_file_errors_name_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("max_range = 50\n[mapping]\nvoxel = 2\n")
    with pytest.raises(ConfigError, match=r"bad\.toml: unknown key 'voxel' in \[mapping\]"):
        load_config(Demo, bad)
    bad.write_text("max_range = \n")
    with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML"):
        load_config(Demo, bad)
    with pytest.raises(FileNotFoundError):
        load_config(Demo, tmp_path / "missing.toml")


def test_presets_merge_order(tmp_path: Path) -> None:
    table = {
        "far": {"max_range": 200.0, "voxel_size": 2.0, "mapping": {"voxel_size": 2.0}},
        "fine": {"voxel_size": 0.25, "mapping": {"deskew": {"reference": "start"}}},
    }
    # defaults < presets in order < file < overrides
    cfg = load_config(Demo, None, presets=["far", "fine"], preset_table=table)
    assert (cfg.max_range, cfg.voxel_size) == (200.0, 0.25)
    assert cfg.mapping == Mapping_(voxel_size=2.0, deskew=Deskew(reference="start"))
    f = tmp_path / "run.toml"
    f.write_text("voxel_size = 0.5\n[mapping.deskew]\nenabled = false\n")
    cfg = load_config(Demo, f, presets=["far", "fine"], preset_table=table)
    assert (cfg.max_range, cfg.voxel_size) == (200.0, 0.5)
    assert cfg.mapping.deskew == Deskew(enabled=False, reference="start")
    assert cfg.mapping.voxel_size == 2.0
    cfg = load_config(Demo, f, presets=["far"], overrides={"voxel_size": 0.1}, preset_table=table)
    assert cfg.voxel_size == 0.1
    assert load_config(Demo, None, presets=["fine", "far"], preset_table=table).voxel_size == 2.0
    with pytest.raises(ConfigError, match=r"preset: unknown 'coarse' \(known: far, fine\)"):
        load_config(Demo, None, presets=["coarse"], preset_table=table)


def test_builtin_sensor_presets() -> None:
    assert {"velodyne-hdl64", "ouster-os1-64", "livox-avia", "sick-2d"} <= set(PRESETS)
    for name in PRESETS:
        cfg = load_config(Demo, None, presets=[name])
        assert cfg.min_range < cfg.max_range and cfg.voxel_size > 0
    hdl = preset("velodyne-hdl64")
    hdl["max_range"] = -1.0  # a copy: the table is not changed
    assert PRESETS["velodyne-hdl64"]["max_range"] > 0
    # a preset key the class does not have is an error naming the preset
    with pytest.raises(ConfigError, match=r"presets sick-2d: unknown key 'max_range'"):
        load_config(RegistrationSettings, None, presets=["sick-2d"])


def test_merge_config_does_not_mutate() -> None:
    base = {"a": 1, "t": {"x": 1, "y": 2}}
    out = merge_config(base, {"t": {"y": 3}, "b": 2})
    assert out == {"a": 1, "b": 2, "t": {"x": 1, "y": 3}}
    assert base == {"a": 1, "t": {"x": 1, "y": 2}}


def test_round_trip_demo(tmp_path: Path) -> None:
    cfg = Demo(
        name='quote " and ünïcode',
        max_range=float("inf"),
        rings=(1, 2),
        scale=0.5,
        mapping=Mapping_(voxel_size=0.3, deskew=Deskew(False, "start")),
    )
    text = dump_config(cfg)
    assert "[mapping]" in text and "[mapping.deskew]" in text
    path = write_config(tmp_path / "effective.toml", cfg)
    assert load_config(Demo, path) == cfg
    none_scale = dataclasses.replace(cfg, scale=None)
    assert "# scale = (unset: None)" in dump_config(none_scale)
    assert load_config(Demo, None, overrides=None) == Demo()


@pytest.mark.parametrize(
    "cfg",
    [
        RegistrationSettings(),
        RegistrationSettings(
            kernel="huber", kernel_scale=0.2, optimizer="levenberg_marquardt", num_threads=2
        ),
        OdometryConfig2D(),
        OdometryConfig2D(front_end="correlative", max_correspondence_distance=0.5),
    ],
)
def test_round_trip_existing_settings(tmp_path: Path, cfg: object) -> None:
    path = write_config(tmp_path / "c.toml", cfg)
    assert load_config(type(cfg), path) == cfg


def test_existing_settings_validation_is_kept() -> None:
    with pytest.raises(ConfigError, match="max_iterations"):
        load_config(RegistrationSettings, {"max_iterations": 0})
    with pytest.raises(ConfigError, match=r"optimizer: expected one of 'gauss_newton'"):
        load_config(RegistrationSettings, {"optimizer": "newton"})
    with pytest.raises(ConfigError, match=r"front_end: expected one of 'icp', 'correlative'"):
        load_config(OdometryConfig2D, {"front_end": "ndt"})


def test_rejects_non_dataclass() -> None:
    with pytest.raises(TypeError, match="dataclass"):
        config_from_dict(dict, {})  # type: ignore[type-var]
    with pytest.raises(TypeError, match="dataclass"):
        dump_config({"a": 1})
