"""The RSU 4.1 Immediate Forward record (bridges.immediate_forward) and the OBU forward formats
(bridges.obu_forward): round trips, the odd records real devices send, and every refusal by its reason.

The J2735 payloads are real traffic from the interop vectors (tests/fixtures/interop), so the message ids
the table routes by are checked against messages other software produced.
"""
from __future__ import annotations

import json
import random
from datetime import datetime, timedelta, timezone

import pytest

from bridges import immediate_forward as imf
from bridges import obu_forward
from bridges.security import PSID_BSM, PSID_SPAT_MAP, PSID_SURROGATE_BSM, ScenarioCA, Signer, oer, time64_us
from conftest import fixture_path

VECTORS = json.loads(fixture_path("interop/j2735_vectors.json").read_text())
ID_OF = {"BSM": 20, "SPaT": 19, "MAP": 18, "SRM": 29, "SSM": 30}


def vector(message: str) -> bytes:
    return bytes.fromhex(next(v["hex"] for v in VECTORS if v["message"] == message))


BSM, SPAT, MAP, SSM, SRM = (vector(m) for m in ("BSM", "SPaT", "MAP", "SSM", "SRM"))
OTHER_BSM = bytes.fromhex([v["hex"] for v in VECTORS if v["message"] == "BSM"][1])  # another vehicle's


@pytest.fixture(scope="module")
def signer():
    start = datetime.now(timezone.utc) - timedelta(hours=1)  # valid from an hour before now
    ca = ScenarioCA.create(start=start)
    return Signer(ca.issue("rsu", [PSID_BSM, PSID_SURROGATE_BSM, PSID_SPAT_MAP], start=start))


def _now_us() -> int:
    return time64_us(datetime.now(timezone.utc).timestamp())


# -- PSIDs and the table ----------------------------------------------------------------------------------
def test_p_encoding_matches_the_registry_values():
    known = {0x20: 0x20, 0x7F: 0x7F, 130: 0x8002, 131: 0x8003, 2113685: 0xE0000015, 2113686: 0xE0000016,
             2113687: 0xE0000017, 0x4080: 0xC00000, 0x407F: 0xBFFF}
    for psid, p in known.items():
        assert imf.p_from_psid(psid) == p and imf.psid_from_p(p) == psid, (psid, hex(p))
    for psid in random.Random(1).sample(range(0, 0x204080 + 0x0FFFFFFF), 2000):
        assert imf.psid_from_p(imf.p_from_psid(psid)) == psid
    for p in (0x80, 0x7FFF, 0xC000, 0xBFFFFF, 0xF0000000):
        with pytest.raises(ValueError):
            imf.psid_from_p(p)


def test_default_table_routes_real_messages_by_their_id():
    routes = imf.DEFAULT_ROUTES
    assert {k: imf.format_psid(routes[k].psid) for k in routes.kinds} == {
        "bsm": "0x20", "surrogate_bsm": "0x7F", "spat": "0x8002", "map": "0x8002", "ssm": "0xE0000015",
        "srm": "0xE0000016"}
    assert routes["spat"].psid_value == PSID_SPAT_MAP and routes["surrogate_bsm"].psid_value == PSID_SURROGATE_BSM
    checked = 0
    for v in VECTORS:
        if v["message"] in ID_OF:
            assert imf.message_id(bytes.fromhex(v["hex"])) == ID_OF[v["message"]], v["source"]
            checked += 1
    assert checked >= 20
    assert routes.for_frame(20).kind == "bsm"
    assert routes.for_frame(20, PSID_SURROGATE_BSM).kind == "surrogate_bsm"
    assert routes.for_frame(19).kind == "spat" and routes.for_frame(18).kind == "map"
    assert routes.for_frame(31) is None
    assert {r.channel for r in imf.default_routes(imf.CV2X_CHANNEL).routes} == {183}


def test_overrides_change_only_what_they_name_and_report_every_problem():
    problems = []
    table = imf.DEFAULT_ROUTES.with_overrides({"map": {"psid": "0xE0000017", "channel": 183}},
                                              lambda k, r: problems.append((k, r)))
    assert problems == []
    assert table["map"].psid == 0xE0000017 and table["map"].channel == 183 and table["spat"].psid == 0x8002
    table.with_overrides({"mapp": {"psid": "0x20"}, "spat": {"psid": "0x82", "chanel": 1, "priority": 9},
                          "ssm": {"psid": 32, "channel": 0}}, lambda k, r: problems.append((k, r)))
    keys = [k for k, _ in problems]
    assert keys == ["mapp", "spat.psid", "spat.chanel", "spat.priority", "ssm.psid", "ssm.channel"], problems
    assert "did you mean 'map'" in problems[0][1] and "0x8002 p-encoded" in problems[1][1]
    assert "did you mean 'channel'" in problems[2][1]


# -- the record -----------------------------------------------------------------------------------------------
def test_record_round_trips_with_every_field():
    rec = imf.Record("SSM", 0xE0000015, SSM, tx_channel=183, priority=5, tx_mode="ALT", tx_interval=100,
                     delivery_start="06/01/2026 12:00", delivery_stop="06/01/2026 13:00", signature=True,
                     encryption=False)
    data = imf.write(rec)
    assert data.decode().splitlines() == [
        "Version=0.7", "Type=SSM", "PSID=0xE0000015", "Priority=5", "TxMode=ALT", "TxChannel=183",
        "TxInterval=100", "DeliveryStart=06/01/2026 12:00", "DeliveryStop=06/01/2026 13:00", "Signature=True",
        "Encryption=False", f"Payload={SSM.hex().upper()}"]
    assert imf.parse(data) == rec
    for payload, typ, psid in ((BSM, "BSM", 0x20), (BSM, "BSM", 0x7F), (SPAT, "SPAT", 0x8002), (MAP, "MAP", 0x8002),
                               (SRM, "SRM", 0xE0000016)):
        rec = imf.Record(typ, psid, payload)
        assert imf.parse(imf.write(rec)) == rec


def test_the_odd_records_real_devices_send_are_read():
    canonical = imf.parse(imf.write(imf.Record("SPAT", 0x8002, SPAT)))
    hexed = SPAT.hex()
    odd = [
        # CRLF line ends, lower-case payload hex
        "\r\n".join(l.replace(SPAT.hex().upper(), hexed) for l in imf.write(canonical).decode().splitlines()),
        # lower-case keys, spaces around keys and values, blank lines, no trailing newline, a lone CR line end
        f"version = 0.7\r\n\n  type=spat \r psid= 0x8002\npriority =7\ntxmode=cont\ntxchannel=172\n"
        f"txinterval=0\ndeliverystart=\ndeliverystop=\nsignature=false\nencryption=FALSE\npayload= {hexed}   ",
        # a byte-order mark and the PSID without 0x, only the required keys
        f"\ufeffVersion=0.7\nType=SPAT\nPSID=8002\nPayload={hexed}\n",
        # tabs
        f"Version\t=\t0.7\nType=\tSPAT\nPSID=0X8002\nPayload=\t{hexed}\t\n",
    ]
    for text in odd:
        assert imf.parse(text.encode("utf-8")) == canonical, text


BAD = [
    (b"\x00\x14\x25\x0d\xff\xfe", imf.Refusal.NOT_TEXT),
    (b"x" * (imf.MAX_RECORD_BYTES + 1), imf.Refusal.OVERSIZE),
    (b"Version=0.7\nType=SPAT\nthis line has no equals sign\n", imf.Refusal.MALFORMED_LINE),
    (b"=0.7\n", imf.Refusal.MALFORMED_LINE),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nPSID=0x8002\nPayload=0013\n", imf.Refusal.DUPLICATE_KEY),
    (b"Version=0.7\nType=SPAT\nPSlD=0x8002\nPayload=0013\n", imf.Refusal.UNKNOWN_KEY),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\n", imf.Refusal.MISSING_KEY),
    (b"Version=0.7\nType=TIM\nPSID=0x8003\nPayload=001f\n", imf.Refusal.UNKNOWN_TYPE),
    (b"Version=0.7\nType=SPAT\nPSID=0x20\nPayload=0013\n", imf.Refusal.WRONG_PSID),
    (b"Version=0.7\nType=BSM\nPSID=0x8002\nPayload=0014\n", imf.Refusal.WRONG_PSID),
    (b"Version=0.7\nType=SPAT\nPSID=spat\nPayload=0013\n", imf.Refusal.PSID_NOT_HEX),
    (b"Version=0.7\nType=SPAT\nPSID=0x82\nPayload=0013\n", imf.Refusal.PSID_NOT_P_ENCODED),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nPayload=0013zz\n", imf.Refusal.PAYLOAD_NOT_HEX),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nPayload=00130\n", imf.Refusal.PAYLOAD_NOT_HEX),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nPayload=0x0013\n", imf.Refusal.PAYLOAD_NOT_HEX),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nPayload=\n", imf.Refusal.PAYLOAD_EMPTY),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nPayload=" + b"00" * (imf.MAX_PAYLOAD_BYTES + 1) + b"\n",
     imf.Refusal.PAYLOAD_OVERSIZE),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nSignature=yes\nPayload=0013\n", imf.Refusal.BAD_VALUE),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nTxMode=BURST\nPayload=0013\n", imf.Refusal.BAD_VALUE),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nPriority=8\nPayload=0013\n", imf.Refusal.BAD_VALUE),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nTxChannel=-1\nPayload=0013\n", imf.Refusal.BAD_VALUE),
    (b"Version=0.7\nType=SPAT\nPSID=0x8002\nTxChannel=0\nPayload=0013\n", imf.Refusal.BAD_VALUE),
    (b"Version=zero\nType=SPAT\nPSID=0x8002\nPayload=0013\n", imf.Refusal.BAD_VALUE),
]


@pytest.mark.parametrize("data, reason", BAD, ids=[f"{r.value}-{i}" for i, (_, r) in enumerate(BAD)])
def test_bad_records_are_refused_with_their_reason(data, reason):
    with pytest.raises(imf.RecordError) as info:
        imf.parse(data)
    assert info.value.reason is reason, info.value
    assert info.value.detail  # says which key or line


def test_the_table_decides_what_psid_a_type_may_have():
    data = imf.write(imf.Record("MAP", 0xE0000017, MAP))
    with pytest.raises(imf.RecordError, match="0xE0000017 is not the table's for MAP"):
        imf.parse(data)
    table = imf.DEFAULT_ROUTES.with_overrides({"map": {"psid": "0xE0000017"}}, pytest.fail)
    assert imf.parse(data, table).psid_value == 2113687
    assert imf.parse(data, None).type == "MAP"  # without a table only the p-encoding is checked


def test_the_writer_refuses_what_the_parser_would():
    for rec, reason in ((imf.Record("SPAT", 0x82, SPAT), imf.Refusal.PSID_NOT_P_ENCODED),
                        (imf.Record("SPAT", 0x8002, b""), imf.Refusal.PAYLOAD_EMPTY),
                        (imf.Record("SPAT", 0x8002, b"\0" * (imf.MAX_PAYLOAD_BYTES + 1)), imf.Refusal.PAYLOAD_OVERSIZE),
                        (imf.Record("SPAT", 0x8002, SPAT, priority=8), imf.Refusal.BAD_VALUE),
                        (imf.Record("SPAT", 0x8002, SPAT, tx_mode="cont"), imf.Refusal.BAD_VALUE),
                        (imf.Record("spat\n", 0x8002, SPAT), imf.Refusal.BAD_VALUE),
                        (imf.Record("SPAT", 0x8002, SPAT, delivery_start="x\nPSID=0x20"), imf.Refusal.BAD_VALUE)):
        with pytest.raises(imf.RecordError) as info:
            imf.write(rec)
        assert info.value.reason is reason, rec
    with pytest.raises(imf.RecordError) as info:
        imf.write(imf.Record("SPAT", 0x20, SPAT), imf.DEFAULT_ROUTES)
    assert info.value.reason is imf.Refusal.WRONG_PSID


def test_garbage_never_raises_anything_but_a_refusal():
    rng = random.Random(7)
    good = imf.write(imf.Record("BSM", 0x20, BSM))
    refused = 0
    for n in range(3000):
        if n % 3 == 0:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300)))
        elif n % 3 == 1:  # a good record with a few bytes changed
            data = bytearray(good)
            for _ in range(rng.randrange(1, 4)):
                data[rng.randrange(len(data))] = rng.randrange(256)
            data = bytes(data)
        else:  # a good record cut short
            data = good[:rng.randrange(len(good))]
        try:
            imf.parse(data)
        except imf.RecordError as exc:
            assert isinstance(exc.reason, imf.Refusal)
            refused += 1
    assert refused > 2000


# -- what an OBU forwards ---------------------------------------------------------------------------------------
def test_every_obu_format_round_trips_what_was_on_the_air(signer):
    signed = signer.sign(BSM, PSID_SURROGATE_BSM, _now_us())
    unsecured = oer.unsecured(SPAT)
    cases = [(obu_forward.OverTheAir(signed, BSM, "BSM", 0x7F, 172, signed=True), PSID_SURROGATE_BSM),
             (obu_forward.OverTheAir(unsecured, SPAT, "SPAT", 0x8002, 183), None)]
    assert obu_forward.formats() == ["bare", "ieee1609dot2", "immediate-forward", "immediate-forward-1609dot2"]
    for air, envelope_psid in cases:
        for name in obu_forward.formats():
            fmt = obu_forward.get_format(name)
            found = fmt.read(fmt.write(air), imf.DEFAULT_ROUTES)
            assert found.frame == air.frame, name
            if name in ("ieee1609dot2", "immediate-forward-1609dot2"):
                assert found.envelope == air.envelope, name
            else:
                assert found.envelope is None, name
            if name == "ieee1609dot2":
                assert found.psid == envelope_psid
            if name.startswith("immediate-forward"):
                assert found.psid == (envelope_psid or imf.psid_from_p(air.psid)), name


def test_a_frame_is_found_only_the_way_the_format_says(signer):
    signed = signer.sign(BSM, PSID_SURROGATE_BSM, _now_us())
    ieee = obu_forward.get_format("ieee1609dot2")
    with pytest.raises(obu_forward.ForwardError) as info:
        ieee.read(BSM, imf.DEFAULT_ROUTES)  # a bare frame where 1609.2 data was promised
    assert info.value.reason == "not-1609dot2"
    with pytest.raises(obu_forward.ForwardError) as info:  # taken as the frame it was said to be, not unwrapped
        obu_forward.get_format("bare").read(signed, imf.DEFAULT_ROUTES)
    assert info.value.reason == "unknown-message"  # 0x03 0x81 read as a message id: 897
    record = imf.write(imf.Record("BSM", 0x7F, signed))
    with pytest.raises(obu_forward.ForwardError) as info:
        obu_forward.get_format("immediate-forward").read(record, imf.DEFAULT_ROUTES)
    assert info.value.reason == "unknown-message"  # 1609.2 data in a record that promised a frame
    with pytest.raises(obu_forward.ForwardError) as info:
        obu_forward.get_format("immediate-forward-1609dot2").read(imf.write(imf.Record("BSM", 0x20, BSM)),
                                                                  imf.DEFAULT_ROUTES)
    assert info.value.reason == "not-1609dot2"


@pytest.mark.parametrize("name, data, reason", [
    ("bare", b"", "empty"),
    ("bare", b"\x80\x14\x00", "not-a-message-frame"),
    ("bare", b"\x00", "not-a-message-frame"),
    ("bare", bytes.fromhex("001f0000"), "unknown-message"),  # a TIM: the table has no route for it
    ("bare", b"\0" * 70000, "oversize"),
    ("ieee1609dot2", b"\x03\x80\xff\x00", "not-1609dot2"),
    ("ieee1609dot2", b"garbage", "not-1609dot2"),
    ("immediate-forward", b"Version=0.7\nType=SPAT\nPSID=0x20\nPayload=0013\n", "record:wrong-psid"),
    ("immediate-forward", b"\xff\xfe", "record:not-text"),
    ("immediate-forward-1609dot2", b"Version=0.7\nType=SPAT\nPSID=0x8002\nPayload=zz\n", "record:payload-not-hex"),
])
def test_unreadable_forwards_are_refused_by_reason(name, data, reason):
    with pytest.raises(obu_forward.ForwardError) as info:
        obu_forward.get_format(name).read(data, imf.DEFAULT_ROUTES)
    assert info.value.reason == reason


def test_an_unknown_format_name_is_refused_with_the_known_ones():
    with pytest.raises(ValueError, match=r"did you mean 'ieee1609dot2'\?") as info:
        obu_forward.get_format("ieee1609.2")
    assert "bare" in str(info.value)
