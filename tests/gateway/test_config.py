"""The gateway's config file: the shipped default, a full file read back, and every bad input
as one line naming the file, the key and the problem."""

from __future__ import annotations

import pytest

from vecu.errors import UserError
from vecu.gateway.config import (
    DEFAULT_ROUTES,
    DEFAULT_TOML,
    EcuRoute,
    GatewayConfig,
    GatewayConfigError,
    default_config,
    load_gateway_config,
)


def test_the_shipped_default_is_the_documented_routing_table(tmp_path):
    cfg = default_config()
    assert cfg.logical_address == 0x1000 and cfg.tester_addresses == (0x0E00, 0x0FFF)
    assert cfg.functional_address == 0xE400 and cfg.functional_id == 0x7DF
    assert [(r.logical_address, r.request_id, r.response_id, r.addressing) for r in cfg.ecus] == [
        (0x0010, 0x7E0, 0x7E8, "normal_11bit"), (0x0011, 0x7E1, 0x7E9, "normal_11bit")]
    assert cfg.initial_inactivity_s == 2.0 and cfg.general_inactivity_s == 300.0
    assert len(cfg.vin) == 17 and len(cfg.eid) == len(cfg.gid) == 6
    # the printed default, written to a file and read back, is the same configuration; and the
    # dataclass defaults agree with it
    path = tmp_path / "gw.toml"
    path.write_text(DEFAULT_TOML)
    assert load_gateway_config(path) == cfg == GatewayConfig(ecus=DEFAULT_ROUTES)
    empty = tmp_path / "empty.toml"
    empty.write_text("")
    assert load_gateway_config(empty) == cfg


def test_a_full_file_with_every_addressing_mode(tmp_path):
    path = tmp_path / "gw.toml"
    path.write_text('''
vin = "WVWZZZ1JZXW000001"
eid = "00-1A-2B-3C-4D-5E"
gid = "001a2b3c4d5f"
logical_address = 0x2000
tester_addresses = [0x0E80, 0x0E8F]
[doip]
protocol_version = 3
max_sockets = 2
initial_inactivity_s = 1
activation_types = [0x00, 0xE0]
authentication_types = [0xE0]
[[ecu]]
logical_address = 0x0020
request_id = 0x7E0
response_id = 0x7E8
p2_ms = 25
[[ecu]]
name = "body"
logical_address = 0x0021
addressing = "normal_fixed_29bit"
target_address = 0x40
[[ecu]]
name = "ext"
logical_address = 0x0022
addressing = "extended"
request_id = 0x600
response_id = 0x680
target_address = 0x12
''')
    cfg = load_gateway_config(path)
    assert cfg.vin == "WVWZZZ1JZXW000001" and cfg.eid == bytes.fromhex("001a2b3c4d5e")
    assert cfg.gid == bytes.fromhex("001a2b3c4d5f") and cfg.protocol_version == 3
    assert cfg.initial_inactivity_s == 1.0 and isinstance(cfg.initial_inactivity_s, float)
    assert cfg.activation_types == (0x00, 0xE0) and cfg.authentication_types == (0xE0,)
    a, body, ext = cfg.ecus
    assert a == EcuRoute("ecu0", 0x20, 0x7E0, 0x7E8, p2_ms=25.0)
    assert (body.request_id, body.response_id) == (0x18DA40F1, 0x18DAF140)  # ISO 15765-2
    assert body.extended_ids and not ext.extended_ids and ext.target_address == 0x12
    assert cfg.route(0x0021) is body and cfg.route(0x0030) is None


BAD = [
    ('vin = "SHORT"', "vin", "17 printable ASCII characters"),
    ('eid = "02:00:00"', "eid", "expected 6 bytes, got 3"),
    ('gid = "zz"', "gid", "expected 6 hex bytes"),
    ("logical_address = 0x10000", "logical_address", "0x10000 is outside 0x0001..0x7FFF"),
    ("logical_address = 0x0E10", "logical_address", "in the tester_addresses range"),
    ("tester_addresses = [0x0FFF, 0x0E00]", "tester_addresses", "first <= last"),
    ("functional_address = 0x1234", "functional_address", "outside 0xE000..0xEFFF"),
    ("functional_id = 0x7E0", "functional_id", "0x07E0 is already ecu[0]'s"),
    ('functional_addressing = "extended"', "functional_addressing", "expected one of"),
    ("colour = 1", "colour", "unknown key"),
    ("[doip]\nmax_sockets = 0", "doip.max_sockets", "0 is outside 1..255"),
    ("[doip]\nmax_sockets = 2.5", "doip.max_sockets", "expected an integer, got a number"),
    ("[doip]\nprotocol_version = 4", "doip.protocol_version", "outside 2..3"),
    ("[doip]\ninitial_inactivity_s = nan", "doip.initial_inactivity_s", "finite"),
    ("[doip]\nauthentication_types = [0x05]", "doip.authentication_types",
     "not in doip.activation_types"),
    ("[doip]\nactivation_types = [256]", "doip.activation_types", "0x00..0xFF"),
    ("[[ecu]]\nrequest_id = 0x7E0\nresponse_id = 0x7E8", "ecu[0].logical_address",
     "required key missing"),
    ("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E0", "ecu[0].response_id",
     "required key missing"),
    (("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E0\nresponse_id = 0x7E8\n"
     "addressing = 'can-fd'"), "ecu[0].addressing", "expected one of normal_11bit"),
    ("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x800\nresponse_id = 0x7E8",
     "ecu[0].request_id", "0x0800 is not an 11-bit ID"),
    ("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E0\nresponse_id = 0x7E8\np2_ms = 0",
     "ecu[0].p2_ms", "outside 1..65535"),
    (("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E0\nresponse_id = 0x7E8\n"
     "p2_ms = 900\np2_star_ms = 500"), "ecu[0].p2_star_ms", "shorter than p2_ms"),
    ("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E0\nresponse_id = 0x7E0",
     "ecu[0].response_id", "0x07E0 is already ecu[0]'s"),
    ("[[ecu]]\nlogical_address = 0x1000\nrequest_id = 0x7E0\nresponse_id = 0x7E8",
     "ecu[0].logical_address", "the gateway's own"),
    ("[[ecu]]\nlogical_address = 0x0E01\nrequest_id = 0x7E0\nresponse_id = 0x7E8",
     "ecu[0].logical_address", "tester_addresses range"),
    (("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E0\nresponse_id = 0x7E8\n"
     "[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E1\nresponse_id = 0x7E9"),
     "ecu[1].logical_address", "0x0010 is already ecu[0]'s"),
    (("[[ecu]]\nlogical_address = 0x10\nrequest_id = 0x7E0\nresponse_id = 0x7E8\n"
     "[[ecu]]\nlogical_address = 0x11\nrequest_id = 0x7E8\nresponse_id = 0x7E9"),
     "ecu[1].request_id", "0x07E8 is already ecu[0]'s"),
    ("[[ecu]]\nlogical_address = 0x10\naddressing = 'normal_fixed_29bit'",
     "ecu[0].target_address", "required with addressing 'normal_fixed_29bit'"),
    (("[[ecu]]\nlogical_address = 0x10\naddressing = 'normal_fixed_29bit'\n"
     "target_address = 0x40\nrequest_id = 0x18DA40F2"), "ecu[0].request_id",
     "not 0x18DA40F1, the normal fixed ID"),
    (("[[ecu]]\nlogical_address = 0x10\naddressing = 'extended'\nrequest_id = 0x7E0\n"
     "response_id = 0x7E8\ntarget_address = 0x100"), "ecu[0].target_address",
     "0x0100 is outside 0x0000..0x00FF"),
    ("[[ecu]]\nname = 1\nlogical_address = 0x10", "ecu[0].name", "expected a string"),
    ("ecu = 3", "ecu", "expected an array"),
    ("ecu = [3]", "ecu[0]", "expected a table"),
]


@pytest.mark.parametrize(("text", "key", "problem"), BAD)
def test_each_bad_input_is_one_line_naming_the_file_and_the_key(tmp_path, text, key, problem):
    path = tmp_path / "gw.toml"
    path.write_text(text + "\n")
    with pytest.raises(GatewayConfigError) as err:
        load_gateway_config(path)
    message = str(err.value)
    assert isinstance(err.value, UserError) and "\n" not in message
    assert message.startswith(f"{path}: key '{key}': "), message
    assert problem in message, message


def test_unreadable_files_are_one_line_too(tmp_path):
    with pytest.raises(GatewayConfigError, match="no such file"):
        load_gateway_config(tmp_path / "missing.toml")
    bad = tmp_path / "syntax.toml"
    bad.write_text("vin = \n")
    with pytest.raises(GatewayConfigError, match="syntax.toml: TOML syntax error"):
        load_gateway_config(bad)


def test_docs_print_the_default_as_shipped():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "gateway.md").read_text()
    assert "```toml\n" + DEFAULT_TOML + "```" in doc
    for key in [*DEFAULT_TOML.split("[doip]")[1].split("[[ecu]]")[0].splitlines()]:
        name = key.split("=")[0].strip()
        if name and not name.startswith("#"):
            assert f"`doip.{name}`" in doc or f"doip.{name}`" in doc, name
