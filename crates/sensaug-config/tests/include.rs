//! `include`: files merged where they are read, a setting from one file
//! only, cycles and missing files refused by entry, paths relative to the
//! including file, and each included file recorded with its SHA-256.

use sensaug_config::{load_file, load_str, parse_file, ConfigError, Format};
use std::path::{Path, PathBuf};

mod common;
/// A trial's phases, every table default.
const PHASES: &str = common::MINIMAL;

const CALIBRATION: &str = "[plant]\nmass = 0.0041\ndamping = 0.0\n\n\
                           [rig.friction]\ncoulomb_nm = 0.02\nviscous_nm_s_per_rad = 0.005\n";

/// A fresh folder for one test (removed first if a run left it).
fn folder(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sensaug_include_{}_{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(&path, text).unwrap();
    path
}

/// `rig.toml` in `dir`: `include = INCLUDE`, the phases, then `rest`.
fn rig_including(dir: &Path, include: &str, rest: &str) -> PathBuf {
    write(
        dir,
        "rig.toml",
        &format!("include = {include}\n{PHASES}{rest}"),
    )
}

fn sha256_hex(text: &str) -> String {
    // The record's digest, checked against an independent tool's output
    // for one file below; here the expected value for the others.
    let out = std::process::Command::new("sha256sum")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .and_then(|mut c| {
            use std::io::Write;
            c.stdin.take().unwrap().write_all(text.as_bytes())?;
            c.wait_with_output()
        })
        .expect("sha256sum (coreutils) runs");
    String::from_utf8(out.stdout).unwrap()[..64].to_string()
}

fn err(path: &Path) -> ConfigError {
    load_file(path).expect_err("refused")
}

#[test]
fn an_included_fragment_gives_its_settings_and_is_recorded() {
    let dir = folder("merge");
    write(&dir, "handles/a.toml", CALIBRATION);
    let top = rig_including(
        &dir,
        "[\"handles/a.toml\"]",
        "\n[rig]\ncan = \"udp:47001\"\n",
    );
    let merged = write(
        &dir,
        "merged.toml",
        &format!("{PHASES}\n{CALIBRATION}\n[rig]\ncan = \"udp:47001\"\n"),
    );
    let with = load_file(&top).unwrap();
    let by_hand = load_file(&merged).unwrap();
    assert_eq!(with.spec.plant.mass, 0.0041);
    assert_eq!(with.spec.rig.friction.coulomb_nm, 0.02);
    assert_eq!(with.spec.rig.can, "udp:47001");
    assert!(with.spec.include.is_empty(), "expanded, not kept");
    let [rec] = with.spec.included.as_slice() else {
        panic!("one record: {:?}", with.spec.included)
    };
    assert_eq!(
        Path::new(&rec.path),
        dir.join("handles/a.toml").canonicalize().unwrap()
    );
    assert_eq!(rec.sha256, sha256_hex(CALIBRATION));
    // Everything else is the file written out by hand.
    let mut spec = with.spec.clone();
    spec.included.clear();
    assert_eq!(spec, by_hand.spec);
    assert_eq!(with.robot.gains, by_hand.robot.gains);
    // The record travels with the configuration: written and read back.
    let again = load_str(&sensaug_config::to_toml(&with.spec), Format::Toml).unwrap();
    assert_eq!(again.spec, with.spec);
}

#[test]
fn a_setting_given_in_two_files_is_refused_naming_both() {
    let dir = folder("conflict");
    write(&dir, "cal.toml", CALIBRATION);
    let top = rig_including(&dir, "[\"cal.toml\"]", "\n[plant]\nmass = 0.0035\n");
    let e = err(&top);
    assert_eq!(e.field, "plant.mass");
    let (a, b) = (top.display().to_string(), dir.join("cal.toml"));
    assert!(
        e.message.contains(&a) && e.message.contains(&b.display().to_string()),
        "{e}"
    );
    assert!(e.message.contains("remove it from one of them"), "{e}");
    // Tables merge key by key: another key of [plant] is no conflict.
    let top = rig_including(&dir, "[\"cal.toml\"]", "\n[plant]\ndt_s = 0.002\n");
    let r = load_file(&top).unwrap();
    assert_eq!((r.spec.plant.mass, r.spec.plant.dt_s), (0.0041, 0.002));
    // A list is one value: phases from two files is a conflict.
    write(&dir, "more.toml", PHASES);
    let top = rig_including(&dir, "[\"more.toml\"]", "");
    assert_eq!(err(&top).field, "phases");
}

#[test]
fn nested_includes_resolve_relative_to_each_including_file() {
    let dir = folder("nested");
    write(&dir, "lab/handles/a.toml", CALIBRATION);
    write(
        &dir,
        "lab/hi5.toml",
        "include = [\"handles/a.toml\"]\n[rig]\ntorque_limit_nm = 0.5\n",
    );
    let top = write(
        &dir,
        "trials/t1.toml",
        &format!("include = [\"../lab/hi5.toml\"]\n{PHASES}"),
    );
    let r = load_file(&top).unwrap();
    assert_eq!(r.spec.plant.mass, 0.0041);
    assert_eq!(r.spec.rig.torque_limit_nm, 0.5);
    let paths: Vec<PathBuf> = r
        .spec
        .included
        .iter()
        .map(|i| PathBuf::from(&i.path))
        .collect();
    assert_eq!(
        paths,
        [
            dir.join("lab/hi5.toml").canonicalize().unwrap(),
            dir.join("lab/handles/a.toml").canonicalize().unwrap()
        ]
    );
    // Read from another working folder: the same.
    let r2 = parse_file(&top.canonicalize().unwrap()).unwrap();
    assert_eq!(r2, r.spec);
}

#[test]
fn a_cycle_and_a_file_included_twice_are_refused() {
    let dir = folder("cycle");
    write(
        &dir,
        "b.toml",
        "include = [\"c.toml\"]\n[world]\nseed = 3\n",
    );
    write(
        &dir,
        "c.toml",
        "include = [\"b.toml\"]\n[plant]\ndt_s = 0.002\n",
    );
    let top = write(&dir, "a.toml", &format!("include = [\"b.toml\"]\n{PHASES}"));
    let e = err(&top);
    assert_eq!(e.field, "include[0]");
    assert!(e.message.contains("a cycle"), "{e}");
    assert!(
        e.message.contains("c.toml"),
        "names the including file: {e}"
    );
    // Including itself.
    let top = write(
        &dir,
        "self.toml",
        &format!("include = [\"self.toml\"]\n{PHASES}"),
    );
    assert!(err(&top).message.contains("a cycle"));
    // A diamond: d.toml would give its settings twice.
    write(&dir, "d.toml", "[world]\nseed = 4\n");
    write(&dir, "e.toml", "include = [\"d.toml\"]\n");
    let top = write(
        &dir,
        "f.toml",
        &format!("include = [\"d.toml\", \"e.toml\"]\n{PHASES}"),
    );
    let e = err(&top);
    assert!(e.message.contains("included twice"), "{e}");
}

#[test]
fn a_missing_or_malformed_include_names_the_entry_and_the_path_tried() {
    let dir = folder("missing");
    let top = rig_including(&dir, "[\"handles/nope.toml\"]", "");
    let e = err(&top);
    assert_eq!(e.field, "include[0]");
    let tried = dir.join("handles/nope.toml").display().to_string();
    assert!(e.message.contains("\"handles/nope.toml\""), "{e}");
    assert!(e.message.contains(&tried), "{e}");
    assert!(e.message.contains("relative to the including file"), "{e}");
    // Not a list of paths.
    let top = rig_including(&dir, "\"cal.toml\"", "");
    let e = err(&top);
    assert_eq!(e.field, "include");
    assert!(e.message.contains("list of file paths"), "{e}");
    // A syntax error inside the included file names it.
    write(&dir, "bad.toml", "[plant]\nmass = = 1\n");
    let top = rig_including(&dir, "[\"bad.toml\"]", "");
    let e = err(&top);
    assert_eq!(e.field, "plant.mass");
    assert!(e.message.contains("not valid TOML"), "{e}");
    assert!(e.message.contains("bad.toml"), "{e}");
    // An unreadable file (a folder).
    std::fs::create_dir_all(dir.join("dir.toml")).unwrap();
    let top = rig_including(&dir, "[\"dir.toml\"]", "");
    let e = err(&top);
    assert_eq!(e.field, "include[0]");
    assert!(e.message.contains("\"dir.toml\""), "{e}");
}

#[test]
fn a_bad_value_in_an_included_file_names_that_file() {
    let dir = folder("bad_value");
    write(&dir, "cal.toml", "[plant]\nmass = -1.0\n");
    let top = rig_including(&dir, "[\"cal.toml\"]", "");
    let e = err(&top);
    assert_eq!(e.field, "plant.mass");
    assert!(e.message.contains("(set in"), "{e}");
    assert!(e.message.contains("cal.toml"), "{e}");
    write(&dir, "cal.toml", "[plant]\nmas = 0.004\n");
    let e = err(&top);
    assert_eq!(e.field, "plant.mas");
    assert!(
        e.message.contains("unknown field") && e.message.contains("cal.toml"),
        "{e}"
    );
}

#[test]
fn json_files_include_and_are_included() {
    let dir = folder("json");
    write(
        &dir,
        "cal.json",
        r#"{"plant": {"mass": 0.0041, "damping": 0.0}, "partner": {"q_pos": null, "gains": [0, 0, 2]}}"#,
    );
    let top = rig_including(&dir, "[\"cal.json\"]", "");
    assert_eq!(load_file(&top).unwrap().spec.plant.mass, 0.0041);
    write(&dir, "cal.toml", CALIBRATION);
    let phases = load_file(&top).unwrap().spec.phases;
    let json = serde_json::json!({"include": ["cal.toml"], "phases": phases});
    let top = write(&dir, "rig.json", &json.to_string());
    assert_eq!(load_file(&top).unwrap().spec.rig.friction.coulomb_nm, 0.02);
}

#[test]
fn text_without_a_file_refuses_include() {
    let e = sensaug_config::load_str(&format!("include = [\"cal.toml\"]\n{PHASES}"), Format::Toml)
        .unwrap_err();
    assert_eq!(e.field, "include");
    assert!(e.message.contains("not read from a file"), "{e}");
    assert!(e.message.contains("from_toml(path)"), "{e}");
}

#[test]
fn a_file_without_include_records_nothing() {
    let dir = folder("plain");
    // "include" in a comment: still no include.
    let top = write(&dir, "rig.toml", &format!("# include nothing\n{PHASES}"));
    let r = load_file(&top).unwrap();
    assert!(r.spec.include.is_empty() && r.spec.included.is_empty());
    let json = sensaug_config::to_json(&r.spec);
    assert!(!json.contains("include"), "no key written: {json}");
}
