from dataclasses import dataclass

import pytest

from neumat.core.config import config_from_dict, config_to_dict, parse_value
from neumat.core.errors import InputError, UnknownNameError
from neumat.core.registry import Registry


def test_registry_register_get_build():
    reg = Registry("thing")

    @reg.register("widget")
    def make(size=1):
        return ("widget", size)

    assert reg.get("widget") is make and "widget" in reg
    assert reg.build({"type": "widget", "size": 3}) == ("widget", 3)
    with pytest.raises(InputError, match="already registered"):
        reg.register("widget")(make)
    with pytest.raises(UnknownNameError, match="did you mean widget"):
        reg.get("widgte")
    with pytest.raises(InputError, match="'type'"):
        reg.build({"size": 3})


@dataclass
class Cfg:
    nside: int = 64
    lr: float = 1e-3
    hidden: tuple[int, ...] = (64, 64)
    name: str = "x"
    ema: float | None = None
    flag: bool = False


def test_config_round_trip_and_strictness():
    cfg = config_from_dict(Cfg, {"type": "neubrdf", "nside": 32, "lr": 1, "hidden": [16, 16], "ema": 0.5})
    assert cfg == Cfg(nside=32, lr=1.0, hidden=(16, 16), ema=0.5)
    assert config_from_dict(Cfg, config_to_dict(cfg)) == cfg
    with pytest.raises(InputError, match="unknown key.*nsid"):
        config_from_dict(Cfg, {"nsid": 3})
    with pytest.raises(InputError, match="Cfg.nside: expected an integer"):
        config_from_dict(Cfg, {"nside": 2.5})
    with pytest.raises(InputError, match="Cfg.flag: expected true/false"):
        config_from_dict(Cfg, {"flag": 1})
    with pytest.raises(InputError, match="Cfg.lr: expected a number"):
        config_from_dict(Cfg, {"lr": "fast"})


def test_parse_value():
    assert parse_value("3") == 3 and parse_value("0.5") == 0.5
    assert parse_value("true") is True and parse_value("ggx") == "ggx"
