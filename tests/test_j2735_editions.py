"""J2735 editions (2016, 2020) and wire compatibility with SAE's own ASN.1.

* each edition's TimeMark range and meaning, and the SSP member's name, in the
  codec, the typed API and the CLI;
* MAP restrictionList: RestrictionClassAssignment is not extensible (bits
  derived by hand from X.691);
* reserved codes (secMark 61000..65534): decode -> encode keeps what was received;
* licensed ASN.1 loaded from a folder: the quirks of SAE's files as distributed
  (byte-order mark, Module.Type references, a type name in two modules, the
  2020 names), reproduced by modules written here from the project's own;
* a raw packet with a transport header: find_message_frame, --header.
"""
from __future__ import annotations

import json
import re

import asn1tools
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridges.j2735 import J2735Codec, J2735Error, scales
from bridges.j2735.bsm import Bsm, EmergencyInfo
from bridges.j2735.codec import BUILTIN_MODULE
from bridges.j2735.editions import EDITION_ENV, edition
from bridges.j2735.framing import find_message_frame, parse_header
from bridges.j2735.licensed_asn1 import qualify_references
from master.cli import main
from test_j2735_vectors import VECTORS

CODECS = {name: J2735Codec(asn1_dir=None, edition=name) for name in ("2016", "2020")}


@pytest.fixture(autouse=True)
def _no_environment(monkeypatch):
    """The tests choose editions and folders themselves."""
    monkeypatch.delenv(EDITION_ENV, raising=False)
    monkeypatch.delenv("V2I_J2735_ASN1_DIR", raising=False)


def _spat(min_end: int) -> dict:
    """A SPaT (asn1tools values) with one movement whose minEndTime is the raw TimeMark `min_end`."""
    return {"intersections": [{"id": {"id": 7}, "revision": 1, "status": (b"\x00\x00", 16),
                               "states": [{"signalGroup": 2, "state-time-speed": [
                                   {"eventState": "stop-And-Remain", "timing": {"minEndTime": min_end}}]}]}]}


def _min_end(frame) -> int:
    return frame.message["intersections"][0]["states"][0]["state-time-speed"][0]["timing"]["minEndTime"]


def _bsm(**fields) -> Bsm:
    base = dict(temporary_id=b"\x0a\x0b\x0c\x0d", msg_count=3, sec_mark_ms=4200, latitude=42.28, longitude=-83.74,
                speed=8.5, heading=90.0, width=2.0, length=5.5)
    base.update(fields)
    return Bsm(**base)


# -- editions: names ------------------------------------------------------------------------------
def test_editions_by_name_default_and_environment(monkeypatch):
    assert edition("2016").name == "2016" and edition(2020).name == "2020"
    assert edition(None).name == "2020" and J2735Codec().edition.name == "2020"
    monkeypatch.setenv(EDITION_ENV, "2016")
    assert edition(None).name == "2016" and J2735Codec().edition.name == "2016"


@pytest.mark.parametrize("bad,hint", [("2019", "did you mean '2016' or '2020'?"), ("202O", "did you mean '2020'"),
                                      ("latest", "(2016, 2020)")])
def test_a_bad_edition_is_refused_with_the_known_ones(bad, hint):
    with pytest.raises(J2735Error, match=re.escape(hint)):
        J2735Codec(edition=bad)


def test_a_bad_edition_in_the_environment_names_the_variable(monkeypatch):
    monkeypatch.setenv(EDITION_ENV, "2017")
    with pytest.raises(J2735Error, match=f"{EDITION_ENV}: '2017'.*did you mean '2016'"):
        J2735Codec()


# -- TimeMark, one test per edition -----------------------------------------------------------------
def test_edition_2020_time_marks():
    """0..36111: 36111 unknown, 36000..36009 a leap second's tenths, 36010..36110 reserved."""
    codec, scale = CODECS["2020"], scales.time_mark("2020")
    data = codec.encode(19, _spat(36111))  # a 2020 SPaT whose time is unknown
    assert _min_end(codec.decode(data)) == 36111
    assert scale.from_wire(36111) is None and scale.to_wire(None) == 36111
    assert scale.from_wire(36005) == pytest.approx(3600.5)  # 36001 is no "unknown" here: a leap second
    assert scale.from_wire(36001) == pytest.approx(3600.1)
    assert scale.to_wire(3600.9) == 36009
    reserved = scale.from_wire(36050)
    assert isinstance(reserved, scales.Reserved) and scale.to_wire(reserved) == 36050
    with pytest.raises(J2735Error, match="time mark: 3601 s is outside 0..3600.9 s; codes 36010..36110"):
        scale.to_wire(3601.0)


def test_edition_2016_time_marks():
    """0..36001: 36001 unknown, 36000 more than an hour; a 2020 'unknown' is out of range."""
    codec, scale = CODECS["2016"], scales.time_mark("2016")
    assert _min_end(codec.decode(codec.encode(19, _spat(36001)))) == 36001
    assert scale.from_wire(36001) is None and scale.to_wire(None) == 36001
    assert scale.to_wire(3600.0) == 36000
    with pytest.raises(J2735Error, match="value out of range"):
        codec.decode(CODECS["2020"].encode(19, _spat(36111)))
    with pytest.raises(J2735Error, match="out of range"):
        codec.encode(19, _spat(36111))
    with pytest.raises(J2735Error, match="time mark: 3600.1 s is outside 0..3600 s"):
        scale.to_wire(3600.1)


def test_a_time_both_editions_admit_has_the_same_bits():
    assert CODECS["2016"].encode(19, _spat(12345)) == CODECS["2020"].encode(19, _spat(12345))
    assert scales.TIME_MARK is scales.time_mark("2020")  # the default edition's


# -- the SSP member's name --------------------------------------------------------------------------
def test_emergency_alerts_have_each_editions_name_and_the_same_bits():
    bsm = _bsm(emergency=EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency"))
    values = {name: bsm.to_asn1(name)["partII"][0]["partII-Value"]["vehicleAlerts"] for name in CODECS}
    assert "sspRights" in values["2016"] and "notUsed" not in values["2016"]
    assert "notUsed" in values["2020"] and "sspRights" not in values["2020"]
    data = {name: bsm.encode(codec) for name, codec in CODECS.items()}
    assert data["2016"] == data["2020"]  # renamed, not moved: same position, same range
    for reader in CODECS.values():
        back = Bsm.decode(data["2016"], reader)
        assert back.emergency == bsm.emergency and back.encode(reader) == data["2016"]


def test_a_2016_ssp_index_survives_both_editions():
    bsm = _bsm(emergency=EmergencyInfo(siren="inUse", ssp_rights=9))
    data = bsm.encode(CODECS["2016"])
    assert Bsm.decode(data, CODECS["2020"]).emergency.ssp_rights == 9
    raw = CODECS["2020"].decode(data).message["partII"][0]["partII-Value"]["vehicleAlerts"]
    assert raw["notUsed"] == 9


def test_the_wrong_name_for_the_codecs_edition_is_refused_naming_the_member():
    message = _bsm(emergency=EmergencyInfo()).to_asn1("2016")
    with pytest.raises(J2735Error, match="notUsed"):
        CODECS["2020"].encode(20, message)


# -- MAP restrictionList ------------------------------------------------------------------------------
RESTRICTION_MAP = {"msgIssueRevision": 0,
                   "restrictionList": [{"id": 1, "users": [("basicType", "equippedTransit")]}]}
# X.691 UPER, derived by hand (43 bits, padded to 6 octets):
#   MapData: extension bit 0 | 8 OPTIONAL flags 00000010 (only restrictionList) | msgIssueRevision 0 in 7 bits
#   restrictionList SIZE(1..254): count-1 = 0 in 8 bits
#   RestrictionClassAssignment (no extension marker, so no bit): id 1 in 8 bits 00000001
#   users SIZE(1..16): count-1 = 0 in 4 bits | RestrictionUserType CHOICE: extension bit 0, index 0 of 2 in 1 bit
#   RestrictionAppliesTo (14 root values, extensible): extension bit 0, equippedTransit = 1 in 4 bits 0001
#   0 00000010 0000000 | 00000000 | 00000001 | 0000 0 0 | 0 0001 + 00000 padding
#   = 00000001 00000000 00000000 00000001 00000000 00100000 = 01 00 00 01 00 20
# MessageFrame: extension bit 0, messageId 18 in 15 bits (00 12), open type length 6 (06), the 6 octets.
RESTRICTION_MAP_HEX = "010000010020"
RESTRICTION_FRAME_HEX = "0012" "06" + RESTRICTION_MAP_HEX


@pytest.mark.parametrize("name", CODECS)
def test_a_restriction_list_has_the_standards_bits(name):
    codec = CODECS[name]
    assert codec.encode_message("MapData", RESTRICTION_MAP).hex() == RESTRICTION_MAP_HEX
    assert codec.encode(18, RESTRICTION_MAP).hex() == RESTRICTION_FRAME_HEX
    frame = codec.decode(bytes.fromhex(RESTRICTION_FRAME_HEX))  # a standard encoder's bytes read back right
    assert frame.message == RESTRICTION_MAP and frame.length == 9


# -- reserved codes: decode -> encode never fails on what decode accepted --------------------------
def _raw_bsm(**core) -> bytes:
    """A BSM frame built from wire integers (what any sender may put there)."""
    message = _bsm().to_asn1("2020")
    message["coreData"].update(core)
    return CODECS["2020"].encode(20, message)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 65535))
def test_every_sec_mark_the_decoder_accepts_encodes_back_to_the_same_bytes(sec_mark):
    data = _raw_bsm(secMark=sec_mark)
    bsm = Bsm.decode(data)
    assert bsm.encode() == data
    if 61000 <= sec_mark <= 65534:
        assert isinstance(bsm.sec_mark_ms, scales.Reserved) and bsm.sec_mark_ms == sec_mark
    elif sec_mark == 65535:
        assert bsm.sec_mark_ms is None
    else:
        assert bsm.sec_mark_ms == sec_mark and not isinstance(bsm.sec_mark_ms, scales.Reserved)


def test_a_reserved_sec_mark_computed_by_user_code_is_still_refused():
    with pytest.raises(J2735Error, match="secMark: 61500 ms is outside 0..60999 ms; codes 61000..65534 are reserved"):
        _bsm(sec_mark_ms=61500).encode()
    with pytest.raises(J2735Error, match="not a reserved code"):
        scales.SEC_MARK.to_wire(scales.Reserved(60000))


wire_cores = st.fixed_dictionaries({
    "secMark": st.integers(0, 65535), "lat": st.integers(-900000000, 900000001),
    "long": st.integers(-1799999999, 1800000001), "elev": st.integers(-4096, 61439),
    "speed": st.integers(0, 8191), "heading": st.integers(0, 28800), "angle": st.integers(-126, 127),
    "accelSet": st.fixed_dictionaries({"long": st.integers(-2000, 2001), "lat": st.integers(-2000, 2001),
                                       "vert": st.integers(-127, 127), "yaw": st.integers(-32767, 32767)}),
    "accuracy": st.fixed_dictionaries({"semiMajor": st.integers(0, 255), "semiMinor": st.integers(0, 255),
                                       "orientation": st.integers(0, 65535)}),
    "size": st.fixed_dictionaries({"width": st.integers(0, 1023), "length": st.integers(0, 4095)}),
})


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(wire_cores)
def test_every_core_value_the_decoder_accepts_encodes_back(core):
    """Not only secMark: any wire value of BSM core data survives the typed view unchanged."""
    data = _raw_bsm(**core)
    assert Bsm.decode(data).encode() == data


# -- licensed ASN.1 from a folder ----------------------------------------------------------------------
BOM = "\ufeff"


def _cut(text: str, start: str, end: str = "\n}\n") -> tuple[str, str]:
    """`text` without the block from `start` to the next `end`, and the block."""
    i = text.index(start)
    j = text.index(end, i) + len(end)
    return text[:i] + text[j:], text[i:j]


def _replace(text: str, old: str, new: str, count: int = 1) -> str:
    assert text.count(old) == count, (old, text.count(old))
    return text.replace(old, new)


def _modules(text: str) -> dict[str, str]:
    """The project's module file cut into its modules (each `NAME DEFINITIONS ... END`)."""
    return {m.group(1): m.group(0) for m in re.finditer(r"^([A-Z][\w-]*) DEFINITIONS.*?^END$", text, re.M | re.S)}


def sae_like_2016(folder):
    """A 2016-style set written from the project's module: the 2016 types referenced as
    `V2I-J2735-2016.EmergencyDetails` (no IMPORTS), `ITIS.ITIScodes`, a REGION module whose object set has
    the class `V2I-J2735.REG-EXT-ID-AND-TYPE`, a byte-order mark, and an AddGrpB module that defines
    TimeMark, Angle and SpecialVehicleExtensions again (as SAE's 2016 AddGrpB does with the first two)."""
    folder.mkdir(parents=True, exist_ok=True)
    modules = _modules(BUILTIN_MODULE.read_text())
    main = _replace(modules["V2I-J2735"], "IMPORTS TimeMark, EmergencyDetails, PrivilegedEvents, TrailerData "
                                          "FROM V2I-J2735-2020;\n", "")
    main = _replace(main, "vehicleAlerts EmergencyDetails", "vehicleAlerts V2I-J2735-2016.EmergencyDetails")
    main = _replace(main, "trailers TrailerData", "trailers V2I-J2735-2016.TrailerData")
    main = _replace(main, " TimeMark", " V2I-J2735-2016.TimeMark", count=5)
    main = _replace(main, "ITIScodes ::= INTEGER (0..65535)\n", "")
    main = _replace(main, " ITIScodes", " ITIS.ITIScodes", count=2)
    main = _replace(main, "Regions REG-EXT-ID-AND-TYPE ::= { ... }\n", "")
    main = _replace(main, "{Regions}", "{REGION.Reg-Everything}", count=2)
    extra = """
ITIS DEFINITIONS AUTOMATIC TAGS ::= BEGIN
ITIScodes ::= INTEGER (0..65535)
END

REGION DEFINITIONS AUTOMATIC TAGS ::= BEGIN
Reg-Everything V2I-J2735.REG-EXT-ID-AND-TYPE ::= { ... }
END

AddGrpB DEFINITIONS AUTOMATIC TAGS ::= BEGIN
TimeMark ::= SEQUENCE { hour INTEGER (0..23), tenths INTEGER (0..36000) }
Angle ::= INTEGER (0..239)
SpecialVehicleExtensions ::= SEQUENCE { angle Angle, time TimeMark }
END
"""
    (folder / "J2735_2016_like.asn").write_text(BOM + main + "\n\n" + modules["V2I-J2735-2016"] + "\n" + extra,
                                                 encoding="utf-8")
    return folder


def sae_like_2020(folder):
    """A 2020-style set in two files: the project's module with its 2020 types (EmergencyDetails.notUsed),
    VehicleSafetyExtensions moved to its own module and imported, and a Legacy module that defines
    VehicleSafetyExtensions, EmergencyDetails and TimeMark again with 2016 shapes (the IMPORTS choose)."""
    folder.mkdir(parents=True, exist_ok=True)
    modules = _modules(BUILTIN_MODULE.read_text())
    main, block = _cut(modules["V2I-J2735"], "VehicleSafetyExtensions ::= SEQUENCE {")
    main = _replace(main, "FROM V2I-J2735-2020;", "FROM V2I-J2735-2020\n   VehicleSafetyExtensions FROM Safety;")
    safety = ("Safety DEFINITIONS AUTOMATIC TAGS ::= BEGIN\nIMPORTS VehicleEventFlags, PathHistory, PathPrediction, "
              "ExteriorLights FROM V2I-J2735;\n" + block + "END\n")
    legacy = """Legacy DEFINITIONS AUTOMATIC TAGS ::= BEGIN
VehicleSafetyExtensions ::= SEQUENCE { flags BIT STRING (SIZE(8)) }
EmergencyDetails ::= SEQUENCE { sspRights INTEGER (0..31), sirenUse BOOLEAN }
TimeMark ::= INTEGER (0..36001)
END
"""
    (folder / "Messages.asn").write_text(main + "\n\n" + modules["V2I-J2735-2020"] + "\n", encoding="utf-8")
    (folder / "Other.asn").write_text(BOM + safety + "\n" + legacy, encoding="utf-8")
    return folder


def test_the_synthetic_quirks_stop_plain_asn1tools(tmp_path):
    """The test files reproduce the problems: asn1tools alone cannot compile them."""
    for build in (sae_like_2016, sae_like_2020):
        folder = build(tmp_path / build.__name__)
        with pytest.raises((asn1tools.ParseError, asn1tools.CompileError)):
            asn1tools.compile_files([str(p) for p in sorted(folder.iterdir())], "uper")
    text = (tmp_path / "sae_like_2016" / "J2735_2016_like.asn").read_text(encoding="utf-8")
    with pytest.raises(asn1tools.ParseError):  # without the BOM: the prefixed class of REGION's object set
        asn1tools.compile_string(text.lstrip(BOM), "uper")
    folder = sae_like_2020(tmp_path / "no_bom")
    (folder / "Other.asn").write_text((folder / "Other.asn").read_text(encoding="utf-8").lstrip(BOM),
                                      encoding="utf-8")
    spec = asn1tools.compile_files([str(p) for p in sorted(folder.iterdir())], "uper")
    assert "VehicleSafetyExtensions" not in spec.types  # defined twice: asn1tools' own lookup drops it


@pytest.fixture(scope="module", params=["2016", "2020"])
def licensed(request, tmp_path_factory):
    folder = tmp_path_factory.mktemp(f"licensed{request.param}")
    build = sae_like_2016 if request.param == "2016" else sae_like_2020
    return request.param, J2735Codec(build(folder))


def test_licensed_files_load_in_their_own_edition(licensed):
    name, codec = licensed
    assert codec.edition.name == name
    assert any("byte-order mark" in note for note in codec.asn1_notes)
    if name == "2016":
        assert any("ITIS.ITIScodes -> ITIScodes" in note for note in codec.asn1_notes)
        assert any("V2I-J2735.REG-EXT-ID-AND-TYPE -> REG-EXT-ID-AND-TYPE" in note for note in codec.asn1_notes)


def test_licensed_files_give_the_builtin_modules_bytes_and_typed_bsm_round_trips(licensed):
    name, codec = licensed
    builtin = CODECS[name]
    bsm = _bsm(emergency=EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency"))
    data = bsm.encode(codec)
    assert data == bsm.encode(builtin)
    back = Bsm.decode(data, codec)
    assert back.emergency == bsm.emergency and back.encode(codec) == data
    member = "sspRights" if name == "2016" else "notUsed"
    assert member in codec.decode(data).message["partII"][0]["partII-Value"]["vehicleAlerts"]
    for vector in (VECTORS[0], VECTORS[41]):  # part II with VehicleSafetyExtensions; special vehicle + regional
        raw = bytes.fromhex(vector["hex"])
        frame = codec.decode(raw)
        assert frame.message == builtin.decode(raw).message
        assert codec.encode(20, frame.message) == raw[:frame.length]
    assert _min_end(codec.decode(builtin.encode(19, _spat(edition(name).time_mark_unknown)))) == \
        edition(name).time_mark_unknown


def test_licensed_files_refuse_another_edition(licensed, tmp_path):
    name, codec = licensed
    other = "2020" if name == "2016" else "2016"
    with pytest.raises(J2735Error, match=f"edition {other} asked for, but the ASN.1 .* is J2735 {name}"):
        J2735Codec(codec.sources[0].parent, edition=other)
    assert J2735Codec(codec.sources[0].parent, edition=name).edition.name == name


def test_a_prefixed_name_the_module_defines_itself_gets_an_alias():
    """`AddGrpB.Angle` used where another Angle is defined: the alias keeps AddGrpB's meaning."""
    text = """A DEFINITIONS AUTOMATIC TAGS ::= BEGIN
Angle ::= INTEGER (0..28800)
Pair ::= SEQUENCE { own Angle, other AddGrpB.Angle, flag B.Flag }
END
AddGrpB DEFINITIONS AUTOMATIC TAGS ::= BEGIN
Angle ::= INTEGER (0..239)
END
B DEFINITIONS AUTOMATIC TAGS ::= BEGIN
IMPORTS Angle FROM AddGrpB;
Flag ::= BOOLEAN
END
"""
    fixed, notes = qualify_references(text)
    assert "Angle-from-AddGrpB ::= Angle" in fixed and "IMPORTS Angle-from-AddGrpB FROM AddGrpB" in fixed
    pair = asn1tools.compile_string(fixed, "uper").modules["A"]["Pair"]
    pair.check_constraints({"own": 28800, "other": 239, "flag": True})
    with pytest.raises(asn1tools.ConstraintsError, match="between 0 and 239"):
        pair.check_constraints({"own": 0, "other": 240, "flag": True})
    assert len(notes) == 2


def test_qualified_references_merge_into_an_existing_imports_group():
    text = """M DEFINITIONS AUTOMATIC TAGS ::= BEGIN
EXPORTS ALL;
IMPORTS X FROM N;
S ::= SEQUENCE { x X, y N.Y }
END
N DEFINITIONS AUTOMATIC TAGS ::= BEGIN
X ::= INTEGER (0..3)
Y ::= INTEGER (0..7)
END
"""
    fixed, _ = qualify_references(text)
    assert "IMPORTS X, Y FROM N;" in fixed
    assert asn1tools.compile_string(fixed, "uper").modules["M"]["S"].encode({"x": 3, "y": 7}) == b"\xf8"  # 11 111 000


# -- transport headers --------------------------------------------------------------------------------
RAW = next(v for v in VECTORS if v["message"].startswith("RawPacket"))


def test_scan_finds_the_frame_at_the_end_of_a_raw_rsu_packet():
    data = bytes.fromhex(RAW["hex"])
    with pytest.raises(J2735Error):
        CODECS["2020"].decode(data)  # never a silent guess
    found = find_message_frame(data, "scan", CODECS["2020"])
    assert data[found.offset:].hex().startswith(RAW["expected"]["messageframe_starts_with"])
    assert found.frame.type_name == "BasicSafetyMessage" and found.frame.length == len(data) - found.offset
    assert find_message_frame(data, f"skip:{found.offset}").offset == found.offset


def test_header_options_refuse_what_does_not_fit():
    data = bytes.fromhex(RAW["hex"])
    with pytest.raises(J2735Error, match="1609.2 envelope"):
        find_message_frame(data, "skip:26")  # the unsecured wrapper starts there, not the frame
    with pytest.raises(J2735Error, match="no MessageFrame of a known type"):
        find_message_frame(data[:-1], "scan")  # the frame no longer ends the packet
    with pytest.raises(J2735Error, match="ends 1 bytes before"):
        find_message_frame(bytes.fromhex(VECTORS[0]["hex"]) + b"\x00", "skip:0")
    with pytest.raises(J2735Error, match="leaves no bytes"):
        find_message_frame(data, f"skip:{len(data)}")
    with pytest.raises(J2735Error, match="did you mean 'skip:N'"):
        parse_header("skp:3")
    assert parse_header("skip:12") == 12 and parse_header("scan") is None


# -- the command line ---------------------------------------------------------------------------------
def _v2i(capsys, *args) -> tuple[int, str, str]:
    """`v2i j2735 ARGS` in this process: (exit status, stdout, stderr)."""
    try:
        code = main(["j2735", *args])
    except SystemExit as exc:  # argparse refuses a bad flag value
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_edition_and_header(capsys, tmp_path):
    spat_2020_unknown = CODECS["2020"].encode(19, _spat(36111)).hex()
    code, _, err = _v2i(capsys, "decode", "--compact", "--edition", "2016", spat_2020_unknown)
    assert code == 2 and "out of range" in err
    code, out, err = _v2i(capsys, "decode", "--compact", "--edition", "2020", spat_2020_unknown)
    assert code == 0, err
    (tmp_path / "spat.json").write_text(out)
    code, out, _ = _v2i(capsys, "encode", "--edition", "2020", str(tmp_path / "spat.json"))
    assert code == 0 and out.strip().lower() == spat_2020_unknown
    code, _, err = _v2i(capsys, "decode", "--edition", "2019", spat_2020_unknown)
    assert code == 2 and "did you mean '2016' or '2020'?" in err


def test_cli_header(capsys):
    code, _, err = _v2i(capsys, "decode", RAW["hex"])
    assert code == 2 and "--header scan (or skip:30)" in err
    code, out, err = _v2i(capsys, "decode", "--compact", "--header", "scan", RAW["hex"])
    document = json.loads(out)
    assert code == 0 and document["headerBytes"] == 30 and document["messageId"] == 20
    code, out, err = _v2i(capsys, "decode", "--compact", "--header", "skip:26", RAW["hex"])
    wrapped = json.loads(out)
    assert wrapped["ieee1609dot2"] == {"content": "unsecuredData"} and wrapped["headerBytes"] == 26
    assert wrapped["message"] == document["message"]
    code, _, err = _v2i(capsys, "decode", "--header", "skip", RAW["hex"])
    assert code == 2 and "did you mean 'skip:N'" in err


# -- the scenario key ---------------------------------------------------------------------------------
def test_the_scenario_names_the_edition_and_started_apps_get_it(tmp_path):
    """[v2x] j2735_edition is checked with the scenario and handed to started apps as V2I_J2735_EDITION
    (which their default_codec() reads); a participant's own env still wins."""
    from master.links.participants import ParticipantBridge, parse_participants
    from master.links.radio_bridge import parse_v2x

    problems: list[tuple[str, str]] = []
    stations = {"rsu": {"position": [0.0, 0.0, 5.0]}}
    v2x = parse_v2x({"j2735_edition": "2016", "stations": stations}, {}, lambda k, m: problems.append((k, m)))
    assert problems == [] and v2x.j2735_edition == "2016" and v2x.resolved()["j2735_edition"] == "2016"
    unset = parse_v2x({"stations": stations}, {}, lambda k, m: problems.append((k, m)))
    assert unset.j2735_edition is None and "j2735_edition" not in unset.resolved()  # each app's own default
    assert parse_v2x({"j2735_edition": "2019", "stations": stations}, {},
                     lambda k, m: problems.append((k, m))) is None
    assert problems == [("v2x.j2735_edition", "expected one of 2016, 2020, got '2019'; did you mean '2016'?")]
    participants = parse_participants({"transport": "zenoh"}, {"rsu": {"command": ["rsu"]},
                                                               "obu": {"command": ["obu"],
                                                                       "env": {EDITION_ENV: "2020"}}},
                                      tmp_path, lambda k, m: problems.append((k, m)))
    bridge = ParticipantBridge(participants, "lockstep", 1.0, "x")
    assert EDITION_ENV not in bridge.child_env(participants.participants["rsu"])  # [v2x] without the key
    bridge.j2735_edition = v2x.j2735_edition  # what open() takes from the scenario's [v2x]
    assert bridge.child_env(participants.participants["rsu"])[EDITION_ENV] == "2016"
    assert bridge.child_env(participants.participants["obu"])[EDITION_ENV] == "2020"
