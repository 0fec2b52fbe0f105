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


def test_resolve_config_takes_a_config_or_fields_but_not_both():
    from neumat.core.config import resolve_config

    @dataclass
    class Cfg:
        size: int = 4

    assert resolve_config(Cfg, None, {"size": 8}, "m").size == 8
    assert resolve_config(Cfg, Cfg(2), {}, "m").size == 2
    with pytest.raises(InputError, match="m: pass either"):
        resolve_config(Cfg, Cfg(2), {"size": 8}, "m")
    with pytest.raises(InputError, match="m: config must be a"):
        resolve_config(Cfg, {"size": 8}, {}, "m")
    with pytest.raises(InputError, match="unknown key"):
        resolve_config(Cfg, None, {"sise": 8}, "m")
