//! The Rust CiA 402 master against python-canopen, frame by frame.
//!
//! `golden/cia402_frames.json` is python-canopen's output
//! (`tools/make_cia402_golden.py`; `tests/test_cia402_golden.py` checks the
//! committed file is exactly that script's output): its SDO client and
//! server, NMT master and slave, SYNC producer, PDO maps read from
//! `cia402_drive.eds` and EMCY producer. Every frame the master sends
//! (SDO requests, NMT, SYNC, heartbeat, RPDO1) must be byte-identical;
//! every frame it receives (SDO responses and aborts, heartbeats, TPDO1,
//! TPDO2, EMCY) must decode to canopen's values. The object constants and
//! unit defaults must match the EDS as canopen reads it.

use sensaug_bridge::cia402::frames::{self, NmtCommand, NmtState, SdoResponse};
use sensaug_bridge::cia402::{od, CanopenNode, Object, Units};
use sensaug_bridge::Frame;
use serde_json::Value;

fn load() -> Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/golden/cia402_frames.json");
    let text = std::fs::read_to_string(path).expect("golden/cia402_frames.json");
    serde_json::from_str(&text).expect("valid JSON")
}

fn n(v: &Value, key: &str) -> i64 {
    v[key]
        .as_i64()
        .unwrap_or_else(|| panic!("{key} not an integer: {v}"))
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// The golden frame's id and bytes.
fn golden(v: &Value) -> (u32, Vec<u8>) {
    (
        u32::try_from(n(v, "id")).unwrap(),
        hex(v["data"].as_str().unwrap()),
    )
}

fn assert_frame(ours: &Frame, theirs: &Value, case: &Value) {
    let (id, data) = golden(theirs);
    assert!(ours.is_standard_data(), "{case}");
    assert_eq!(
        (ours.id, ours.payload()),
        (id, &data[..]),
        "our frame differs from python-canopen's in {case}"
    );
}

fn node_of(case: &Value) -> CanopenNode {
    // SDO cases carry the node in the request id.
    let id = case
        .get("node")
        .map(|v| v.as_i64().unwrap())
        .unwrap_or_else(|| n(&case["request"], "id") - 0x600);
    CanopenNode::new(u8::try_from(id).unwrap()).unwrap()
}

fn object(case: &Value) -> Object {
    Object {
        index: u16::try_from(n(case, "index")).unwrap(),
        subindex: u8::try_from(n(case, "subindex")).unwrap(),
        name: "golden",
    }
}

/// The value's little-endian bytes at its data type's width.
fn value_bytes(data_type: &str, value: i64) -> Vec<u8> {
    let width = match data_type {
        "INTEGER8" | "UNSIGNED8" => 1,
        "INTEGER16" | "UNSIGNED16" => 2,
        "INTEGER32" | "UNSIGNED32" => 4,
        other => panic!("type {other}"),
    };
    value.to_le_bytes()[..width].to_vec()
}

fn frames_of(doc: &Value, kind: &str) -> Vec<Value> {
    let out: Vec<Value> = doc["frames"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["kind"] == kind)
        .cloned()
        .collect();
    assert!(!out.is_empty(), "no {kind} frames in the golden file");
    out
}

#[test]
fn sdo_requests_match_and_responses_decode() {
    let doc = load();
    for c in frames_of(&doc, "download") {
        let bytes = value_bytes(c["data_type"].as_str().unwrap(), n(&c, "value"));
        let req = frames::sdo_download(node_of(&c), object(&c), &bytes).unwrap();
        assert_frame(&req, &c["request"], &c);
        let (_, resp) = golden(&c["response"]);
        let o = object(&c);
        assert_eq!(
            frames::decode_sdo_response(&resp).unwrap(),
            SdoResponse::Downloaded {
                index: o.index,
                subindex: o.subindex
            },
            "{c}"
        );
    }
    for c in frames_of(&doc, "upload") {
        let req = frames::sdo_upload(node_of(&c), object(&c));
        assert_frame(&req, &c["request"], &c);
        let (_, resp) = golden(&c["response"]);
        let SdoResponse::Uploaded { data, len, .. } = frames::decode_sdo_response(&resp).unwrap()
        else {
            panic!("not an upload response: {c}");
        };
        let want = value_bytes(c["data_type"].as_str().unwrap(), n(&c, "value"));
        assert_eq!(&data[..usize::from(len)], &want[..], "{c}");
    }
}

#[test]
fn sdo_aborts_decode_to_canopens_codes() {
    let doc = load();
    for kind in ["abort_download", "abort_upload"] {
        for c in frames_of(&doc, kind) {
            let (_, req_bytes) = golden(&c["request"]);
            let req = if kind == "abort_upload" {
                frames::sdo_upload(node_of(&c), object(&c))
            } else {
                // The payload canopen tried to write: bytes 4.. of its request,
                // the size from the command byte.
                let size = 4 - usize::from((req_bytes[0] >> 2) & 3);
                frames::sdo_download(node_of(&c), object(&c), &req_bytes[4..4 + size]).unwrap()
            };
            assert_frame(&req, &c["request"], &c);
            let (_, resp) = golden(&c["response"]);
            let o = object(&c);
            assert_eq!(
                frames::decode_sdo_response(&resp).unwrap(),
                SdoResponse::Aborted {
                    index: o.index,
                    subindex: o.subindex,
                    code: u32::try_from(n(&c, "code")).unwrap()
                },
                "{c}"
            );
        }
    }
}

#[test]
fn nmt_sync_and_heartbeats_match() {
    let doc = load();
    for c in frames_of(&doc, "nmt") {
        let cmd = match n(&c, "command") {
            0x01 => NmtCommand::Start,
            0x02 => NmtCommand::Stop,
            0x80 => NmtCommand::EnterPreOperational,
            0x81 => NmtCommand::ResetNode,
            0x82 => NmtCommand::ResetCommunication,
            other => panic!("command {other}"),
        };
        let node = u8::try_from(n(&c, "node")).unwrap();
        assert_frame(&frames::nmt(cmd, node), &c["frame"], &c);
    }
    let mut counted = 0;
    for c in frames_of(&doc, "sync") {
        // The master always sends the counter; canopen's SYNC without one
        // (counter null) is checked to be the empty frame the drive also takes.
        match c["counter"].as_u64() {
            Some(counter) => {
                let counter = u8::try_from(counter).unwrap();
                assert!((1..=od::SYNC_COUNTER_OVERFLOW).contains(&counter));
                assert_frame(&frames::sync(counter), &c["frame"], &c);
                counted += 1;
            }
            None => assert_eq!(golden(&c["frame"]), (od::SYNC_COB_ID, vec![])),
        }
    }
    assert!(counted > 0);
    for c in frames_of(&doc, "heartbeat") {
        let state = match n(&c, "state") {
            0x00 => NmtState::BootUp,
            0x04 => NmtState::Stopped,
            0x05 => NmtState::Operational,
            0x7F => NmtState::PreOperational,
            other => panic!("state {other}"),
        };
        assert_frame(&frames::heartbeat(node_of(&c), state), &c["frame"], &c);
        let (_, data) = golden(&c["frame"]);
        assert_eq!(frames::decode_heartbeat(&data).unwrap(), state);
    }
}

#[test]
fn pdos_match_canopens_maps() {
    let doc = load();
    for c in frames_of(&doc, "rpdo1") {
        let f = frames::rpdo1(
            node_of(&c),
            u16::try_from(n(&c, "controlword")).unwrap(),
            i16::try_from(n(&c, "target_torque")).unwrap(),
        );
        assert_frame(&f, &c["frame"], &c);
    }
    for c in frames_of(&doc, "tpdo1") {
        let (id, data) = golden(&c["frame"]);
        assert_eq!(id, node_of(&c).tpdo1());
        let t = frames::decode_tpdo1(&data).unwrap();
        assert_eq!(i64::from(t.statusword), n(&c, "statusword"), "{c}");
        assert_eq!(i64::from(t.position_increments), n(&c, "position"), "{c}");
        assert_eq!(i64::from(t.sync_counter), n(&c, "sync_counter"), "{c}");
    }
    for c in frames_of(&doc, "tpdo2") {
        let (id, data) = golden(&c["frame"]);
        assert_eq!(id, node_of(&c).tpdo2());
        let t = frames::decode_tpdo2(&data).unwrap();
        assert_eq!(i64::from(t.velocity_increments_s), n(&c, "velocity"), "{c}");
        assert_eq!(i64::from(t.torque_per_mille), n(&c, "torque"), "{c}");
        assert_eq!(i64::from(t.sync_counter), n(&c, "sync_counter"), "{c}");
    }
}

#[test]
fn pdo_remap_writes_are_canopens_pdo_save() {
    let doc = load();
    let cases = frames_of(&doc, "pdo_remap");
    assert!(!cases.is_empty());
    for c in cases {
        let pdo = match c["pdo"].as_str().unwrap() {
            "rpdo1" => od::PDOS[0],
            "tpdo1" => od::PDOS[1],
            "tpdo2" => od::PDOS[2],
            other => panic!("pdo {other}"),
        };
        let cob_id = u32::try_from(n(&c, "cob_id")).unwrap();
        let writes = od::remap_writes(&pdo, cob_id);
        let requests = c["requests"].as_array().unwrap();
        assert_eq!(writes.len(), requests.len(), "{c}");
        for (w, theirs) in writes.iter().zip(requests) {
            let ours = frames::sdo_download(node_of(&c), w.object, &w.bytes()).unwrap();
            assert_frame(&ours, theirs, &c);
        }
    }
}

#[test]
fn emcy_decodes() {
    let doc = load();
    for c in frames_of(&doc, "emcy") {
        let (id, data) = golden(&c["frame"]);
        assert_eq!(id, node_of(&c).emcy());
        let e = frames::decode_emcy(&data).unwrap();
        assert_eq!(i64::from(e.code), n(&c, "code"), "{c}");
        assert_eq!(i64::from(e.register), n(&c, "register"), "{c}");
        assert_eq!(
            e.manufacturer.to_vec(),
            hex(c["manufacturer"].as_str().unwrap())
        );
    }
}

#[test]
fn object_constants_and_defaults_match_the_eds() {
    let doc = load();
    let objects = doc["objects"].as_array().unwrap();
    let find = |o: Object| -> &Value {
        objects
            .iter()
            .find(|v| {
                n(v, "index") == i64::from(o.index) && n(v, "subindex") == i64::from(o.subindex)
            })
            .unwrap_or_else(|| panic!("{o:?} not in the golden objects"))
    };
    // (constant, data type, PDO-mappable)
    let named = [
        (od::DEVICE_TYPE, "UNSIGNED32", false),
        (od::CONSUMER_HEARTBEAT, "UNSIGNED32", false),
        (od::PRODUCER_HEARTBEAT, "UNSIGNED16", false),
        (od::RPDO1_COB_ID, "UNSIGNED32", false),
        (od::RPDO1_TRANSMISSION, "UNSIGNED8", false),
        (od::TPDO1_COB_ID, "UNSIGNED32", false),
        (od::TPDO1_TRANSMISSION, "UNSIGNED8", false),
        (od::TPDO2_COB_ID, "UNSIGNED32", false),
        (od::TPDO2_TRANSMISSION, "UNSIGNED8", false),
        (od::SYNC_COUNTER_ECHO, "UNSIGNED8", true),
        (od::CONTROLWORD, "UNSIGNED16", true),
        (od::STATUSWORD, "UNSIGNED16", true),
        (od::MODES_OF_OPERATION, "INTEGER8", false),
        (od::MODES_OF_OPERATION_DISPLAY, "INTEGER8", false),
        (od::POSITION_ACTUAL, "INTEGER32", true),
        (od::VELOCITY_ACTUAL, "INTEGER32", true),
        (od::TARGET_TORQUE, "INTEGER16", true),
        (od::MAX_TORQUE, "UNSIGNED16", false),
        (od::RATED_TORQUE, "UNSIGNED32", false),
        (od::TORQUE_ACTUAL, "INTEGER16", true),
        (od::ENCODER_INCREMENTS, "UNSIGNED32", false),
        (od::ENCODER_MOTOR_REVOLUTIONS, "UNSIGNED32", false),
        (od::GEAR_MOTOR_REVOLUTIONS, "UNSIGNED32", false),
        (od::GEAR_SHAFT_REVOLUTIONS, "UNSIGNED32", false),
    ];
    for (o, ty, pdo) in named {
        let v = find(o);
        assert_eq!(v["name"], o.name, "{o:?}");
        assert_eq!(v["data_type"], ty, "{o:?}");
        assert_eq!(v["pdo_mappable"], pdo, "{o:?}");
    }
    let default = |o: Object| n(find(o), "default");
    assert_eq!(
        default(od::DEVICE_TYPE) & 0xFFFF,
        i64::from(od::PROFILE_402)
    );
    // The golden objects are read for node 1.
    let node1 = CanopenNode::new(1).unwrap();
    assert_eq!(default(od::RPDO1_COB_ID), i64::from(node1.rpdo1()));
    assert_eq!(default(od::TPDO1_COB_ID), i64::from(node1.tpdo1()));
    assert_eq!(default(od::TPDO2_COB_ID), i64::from(node1.tpdo2()));
    for m in [od::RPDO1_MAPPING, od::TPDO1_MAPPING, od::TPDO2_MAPPING] {
        let count = Object {
            index: m.index,
            subindex: 0,
            name: "",
        };
        assert_eq!(default(count), m.entries.len() as i64);
        for (i, &e) in m.entries.iter().enumerate() {
            let sub = Object {
                index: m.index,
                subindex: i as u8 + 1,
                name: "",
            };
            assert_eq!(default(sub), i64::from(e), "{:#06x}:{}", m.index, i + 1);
            // The mapped object's size is its data type's.
            let mapped = Object {
                index: (e >> 16) as u16,
                subindex: (e >> 8) as u8,
                name: "",
            };
            assert_eq!(n(find(mapped), "bits"), i64::from(e & 0xFF));
        }
    }
    let u = Units::eds_defaults();
    assert_eq!(default(od::RATED_TORQUE), i64::from(u.rated_torque_mnm));
    assert_eq!(default(od::MAX_TORQUE), i64::from(u.max_torque_per_mille));
    assert_eq!(
        default(od::ENCODER_INCREMENTS),
        i64::from(u.encoder_increments)
    );
    assert_eq!(
        default(od::ENCODER_MOTOR_REVOLUTIONS),
        i64::from(u.encoder_motor_revs)
    );
    assert_eq!(
        default(od::GEAR_MOTOR_REVOLUTIONS),
        i64::from(u.gear_motor_revs)
    );
    assert_eq!(
        default(od::GEAR_SHAFT_REVOLUTIONS),
        i64::from(u.gear_shaft_revs)
    );
}
