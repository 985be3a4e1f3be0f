"""Line framing and parsing of Marlin replies (pure functions)."""

from hostd.printer import protocol
from hostd.printer.firmware import words
from hostd.printer.simconfig import SimConfig
from hostd.printer.errors import PrinterError

import pytest


def test_frame_has_marlin_xor_checksum():
    data = protocol.frame(1, "G1 X10")
    body, cs = data.rstrip(b"\n").split(b"*")
    expected = 0
    for byte in b"N1 G1 X10":
        expected ^= byte
    assert body == b"N1 G1 X10" and int(cs) == expected
    assert protocol.unframe(data) == (1, "G1 X10", True)


def test_unframe_detects_corruption_and_missing_checksum():
    data = bytearray(protocol.frame(7, "G1 X10 Y20"))
    data[6] ^= 0x01
    assert protocol.unframe(bytes(data))[2] is False
    assert protocol.unframe(b"N7 G1 X1") == (7, "G1 X1", None)


def test_clean_strips_comments_and_blank_lines():
    assert protocol.clean("G1 X1 ; go *there*") == "G1 X1"
    assert protocol.clean("   ; only a comment") == ""


@pytest.mark.parametrize("raw, kind, line, planner, buffer", [
    (b"ok", "ok", None, None, None),
    (b"ok N12 P15 B3", "ok", 12, 15, 3),
    (b"ok P4 B0\r", "ok", None, 4, 0),
    (b"Resend: 42", "resend", 42, None, None),
    (b"rs N42", "resend", 42, None, None),
    (b"echo:busy: processing", "busy", None, None, None),
    (b"wait", "busy", None, None, None),
    (b"start", "start", None, None, None),
])
def test_parse_reply_kinds(raw, kind, line, planner, buffer):
    reply = protocol.parse_reply(raw)
    assert (reply.kind, reply.line, reply.planner_free, reply.buffer_free) == (kind, line, planner, buffer)


def test_host_action_commands():
    for raw, name in ((b"//action:cancel", "cancel"), (b"// action:pause", "pause"),
                      (b"//action:paused filament_runout 1", "paused"),
                      (b"//action:prompt_begin Filament Runout", "prompt_begin")):
        reply = protocol.parse_reply(raw)
        assert (reply.kind, reply.action) == ("action", name), raw
    assert protocol.parse_reply(b"echo://action:cancel").kind != "action"


def test_errors_are_kept_verbatim_and_classified():
    runaway = protocol.parse_reply(b"Error:Thermal Runaway, system stopped! Heater_ID: 0")
    assert runaway.kind == "error" and runaway.text == "Error:Thermal Runaway, system stopped! Heater_ID: 0"
    assert not protocol.is_resend_error(runaway.text)
    for text in ("Error:checksum mismatch, Last Line: 4",
                 "Error:Line Number is not Last Line Number+1, Last Line: 4",
                 "Error:No Checksum with line number, Last Line: 4"):
        assert protocol.is_resend_error(text)


def test_temperatures_from_ok_and_autoreport():
    reply = protocol.parse_reply(b"ok T:201.3 /210.0 B:59.9 /60.0 @:127 B@:0")
    assert reply.kind == "ok"
    assert reply.temps == {"T": (201.3, 210.0), "B": (59.9, 60.0)}
    auto = protocol.parse_reply(b" T:25.00 /0.00 T0:25.00 /0.00 T1:30.5 /200.00 B:24.90 /0.00 @:0 B@:0")
    assert auto.kind == "temps" and auto.temps["T1"] == (30.5, 200.0) and "@" not in auto.temps


def test_noise_is_tolerated():
    reply = protocol.parse_reply(b"\xff\xfe\x00garbage\x81")
    assert reply.kind == "other"
    assert protocol.parse_reply(b"\x00\x13ok N3 P1 B2").kind == "ok"


def test_capabilities_and_firmware_info():
    assert protocol.parse_reply(b"Cap:ADVANCED_OK:1").cap == ("ADVANCED_OK", True)
    info = protocol.parse_firmware_info("FIRMWARE_NAME:Marlin 2.1.2 (x) SOURCE_CODE_URL:github.com/a "
                                        "PROTOCOL_VERSION:1.0 MACHINE_TYPE:Ender EXTRUDER_COUNT:1")
    assert info["FIRMWARE_NAME"] == "Marlin 2.1.2 (x)" and info["EXTRUDER_COUNT"] == "1"


def test_gcode_words():
    assert words("G01 X1.5 F600") == ("G1", {"X": 1.5, "F": 600.0})
    assert words("M104 S200")[0] == "M104" and words("T0")[0] == "T0"
    assert words("45 G1 X1")[0] == ""      # tail of a cut line: not a command


def test_sim_url_options():
    config = SimConfig.from_url("sim://?advanced_ok=1&planner=8&time_scale=0.01&seed=3&fault_corrupt=0.01")
    assert (config.advanced_ok, config.planner, config.time_scale, config.seed, config.fault_corrupt) == \
        (True, 8, 0.01, 3, 0.01)
    with pytest.raises(PrinterError) as err:
        SimConfig.from_url("sim://?planer=8")
    assert err.value.code == "config"


def test_fragment_echo_is_recognised():
    assert protocol.is_fragment_echo('echo:Unknown command: "07"')
    assert not protocol.is_fragment_echo('echo:Unknown command: "M999"')
