//! Output paths: the files a rig run writes (`rig.log`, `rig.stats`, and the
//! Python launcher's configuration copy, bus capture and README). Each must
//! be a regular file or absent — never a device, a FIFO, a socket, a
//! directory or a symbolic link (to anything) — and no two may be the same
//! file, counting the `<path>.partial` each output is written as until it
//! is complete and renamed over `<path>` (`docs/safety.md`, "Output paths").
//!
//! Both checkers (`sensaug check`, `sensaug-rt --check`) and the run itself,
//! before the drive is enabled, call [`check_outputs`]; it only looks
//! (`lstat`), never opens, so a FIFO cannot block it. This reads the file
//! system: the same configuration can be valid in one folder and refused in
//! another. The writers then create `<path>.partial` with
//! [`create_partial`] (never opening what is there) and rename it over the
//! path with [`replace`] (never over anything but a regular file).

use crate::error::ConfigError;
use crate::ScenarioSpec;
use std::fs::{File, FileType, OpenOptions};
use std::io;
use std::os::unix::fs::FileTypeExt;
use std::path::{Component, Path, PathBuf};

/// `<path>.partial`: where an output is written until it is complete.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".partial");
    PathBuf::from(name)
}

/// The rig's own outputs, by field: `rig.log`, `rig.stats`.
pub fn rig_outputs(spec: &ScenarioSpec) -> [(&'static str, PathBuf); 2] {
    [
        ("rig.log", PathBuf::from(&spec.rig.log)),
        ("rig.stats", PathBuf::from(&spec.rig.stats)),
    ]
}

/// Creates `<path>.partial` (and its folder) for an output, opening nothing
/// that is already there: a regular file left by an earlier run killed
/// before its rename is removed first; anything else (a FIFO, a device, a
/// link, a folder) is refused. The open is `O_CREAT | O_EXCL`, so whatever
/// appears there meanwhile fails it instead of blocking it or being followed.
pub fn create_partial(path: &Path) -> io::Result<File> {
    if let Some(dir) = path.parent() {
        if !dir.as_os_str().is_empty() {
            std::fs::create_dir_all(dir)?;
        }
    }
    let partial = partial_path(path);
    if let Some(what) = not_replaceable(&partial) {
        return Err(io::Error::other(format!(
            "{} is {what}; remove it",
            partial.display()
        )));
    }
    match std::fs::remove_file(&partial) {
        Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&partial)
}

/// Renames `<path>.partial` over `path` if `path` is absent or a regular
/// file; anything else stays and the output stays at `<path>.partial`.
pub fn replace(path: &Path) -> io::Result<()> {
    if let Some(what) = not_replaceable(path) {
        return Err(io::Error::other(format!(
            "{} is {what}, not replaced: the output stays at {}",
            path.display(),
            partial_path(path).display()
        )));
    }
    std::fs::rename(partial_path(path), path)
}

/// Writes an output whole: `write` fills `<path>.partial` ([`create_partial`]),
/// which is then renamed over `path` ([`replace`]), so an older regular file
/// is replaced only by a complete one. On failure the `.partial` is removed.
pub fn write_replacing(
    path: &Path,
    write: impl FnOnce(&mut io::BufWriter<File>) -> io::Result<()>,
) -> io::Result<()> {
    let mut out = io::BufWriter::new(create_partial(path)?);
    // Flushed here: a BufWriter dropped unflushed loses a full disk's error.
    let written = write(&mut out).and_then(|()| io::Write::flush(&mut out));
    drop(out);
    finish_partial(path, written)
}

/// Ends an output written to `<path>.partial`: when `written` is `Ok`, the
/// `.partial` is renamed over `path` ([`replace`]); when that or the
/// writing failed, the `.partial` is removed. Returns the first error.
pub fn finish_partial(path: &Path, written: io::Result<()>) -> io::Result<()> {
    let done = written.and_then(|()| replace(path));
    if done.is_err() {
        let _ = std::fs::remove_file(partial_path(path));
    }
    done
}

/// A file type's test (`FileType::is_file`, `FileTypeExt::is_fifo`, ...).
type IsKind = fn(&FileType) -> bool;

/// What a file type is called in messages ("a FIFO", "a character device").
pub fn kind_name(t: FileType) -> &'static str {
    let kinds: [(IsKind, &str); 7] = [
        (FileType::is_file, "a regular file"),
        (FileType::is_dir, "a directory"),
        (FileType::is_symlink, "a symbolic link"),
        (FileTypeExt::is_fifo, "a FIFO (named pipe)"),
        (FileTypeExt::is_char_device, "a character device"),
        (FileTypeExt::is_block_device, "a block device"),
        (FileTypeExt::is_socket, "a socket"),
    ];
    kinds
        .iter()
        .find(|(is, _)| is(&t))
        .map_or("not a regular file", |&(_, name)| name)
}

/// What is at `path`, the last component not followed; `None` when nothing.
pub fn file_type(path: &Path) -> io::Result<Option<FileType>> {
    match std::fs::symlink_metadata(path) {
        Ok(m) => Ok(Some(m.file_type())),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e),
    }
}

/// What is at `path` when it may not be replaced by a new output ("a FIFO
/// (named pipe)", "a symbolic link to /dev/full (a character device)"), or
/// `None` when it may: nothing is there, or a regular file. Checked before
/// every rename.
pub fn not_replaceable(path: &Path) -> Option<String> {
    match file_type(path) {
        Ok(None) => None,
        Ok(Some(t)) if t.is_file() => None,
        Ok(Some(t)) if t.is_symlink() => Some(match std::fs::read_link(path) {
            Ok(target) => {
                let what = std::fs::metadata(path)
                    .map_or("which does not exist", |m| kind_name(m.file_type()));
                format!("a symbolic link to {} ({what})", target.display())
            }
            Err(_) => "a symbolic link".into(),
        }),
        Ok(Some(t)) => Some(kind_name(t).into()),
        Err(e) => Some(format!("not checkable ({e})")),
    }
}

/// How sensaug-rt's command line overrides a rig output, for messages.
fn option_hint(field: &str) -> &'static str {
    match field {
        "rig.log" => " (--log)",
        "rig.stats" => " (--stats)",
        _ => "",
    }
}

/// Checks that each `(field, path)` may be written as an output: it and its
/// `<path>.partial` are regular files or absent, its folder is a folder (or
/// will be created), and no two outputs (or their `.partial`) are the same
/// file. The first problem, at its field.
pub fn check_outputs(outputs: &[(impl AsRef<str>, impl AsRef<Path>)]) -> Result<(), ConfigError> {
    // Every file written so far: where, and what it is, for the message.
    let mut taken: Vec<(PathBuf, String)> = Vec::new();
    for (field, path) in outputs {
        let (field, path) = (field.as_ref(), path.as_ref());
        check_one(field, path)?;
        for (file, temporary) in [(path.to_path_buf(), false), (partial_path(path), true)] {
            let id = identity(&file);
            if let Some((_, other)) = taken.iter().find(|(p, _)| *p == id) {
                let which = if temporary {
                    format!("{}'s temporary file {}", path.display(), file.display())
                } else {
                    path.display().to_string()
                };
                return Err(ConfigError::new(
                    field,
                    format!(
                        "{which} is the same file as {other}; give each output its own path{}",
                        option_hint(field)
                    ),
                ));
            }
            let what = if temporary {
                format!("{field}'s temporary file")
            } else {
                format!("{field} ({})", path.display())
            };
            taken.push((id, what));
        }
    }
    Ok(())
}

fn check_one(field: &str, path: &Path) -> Result<(), ConfigError> {
    let hint = option_hint(field);
    let shown = path.display();
    let err = |m: String| {
        Err(ConfigError::new(
            field,
            format!("cannot write {shown}: {m}{hint}"),
        ))
    };
    let text = path.as_os_str().to_string_lossy();
    let named = matches!(path.components().next_back(), Some(Component::Normal(_)));
    if text.is_empty() || text.ends_with('/') || !named {
        return Err(ConfigError::new(
            field,
            format!("{text:?} does not end in a file name; give a file path (e.g. out/rig_log.csv){hint}"),
        ));
    }
    // The nearest existing ancestor must be a folder (the rest is created).
    let mut folder = path.parent();
    while let Some(dir) = folder.filter(|d| !d.as_os_str().is_empty()) {
        match std::fs::metadata(dir) {
            Ok(m) if m.is_dir() => break,
            Ok(m) => {
                return err(format!(
                    "its folder {} is {}, not a directory; give a path in a folder",
                    dir.display(),
                    kind_name(m.file_type())
                ))
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => folder = dir.parent(),
            Err(e) => {
                return err(format!(
                    "its folder {} cannot be checked ({e})",
                    dir.display()
                ))
            }
        }
    }
    match (not_replaceable(path), file_type(path)) {
        (None, _) => {}
        (Some(_), Ok(Some(t))) if t.is_dir() => {
            return err(format!(
                "it is a directory, not a regular file; give a file path inside it (e.g. {})",
                path.join("rig_log.csv").display()
            ))
        }
        (Some(what), _) => {
            return err(format!(
                "it is {what}, not a regular file; give the path of a regular file or a new one"
            ))
        }
    }
    let partial = partial_path(path);
    if let Some(what) = not_replaceable(&partial) {
        return err(format!(
            "{} (where it is written until the run ends) is {what}; remove it or give another path",
            partial.display()
        ));
    }
    Ok(())
}

/// The file `path` names, comparable between outputs: absolute, its
/// longest existing ancestor with symbolic links resolved, the rest
/// normalized without touching the file system.
fn identity(path: &Path) -> PathBuf {
    let absolute = std::env::current_dir()
        .map(|cwd| cwd.join(path))
        .unwrap_or_else(|_| path.to_path_buf());
    let parts: Vec<Component> = absolute.components().collect();
    // The longest prefix that exists, resolved; the rest as written.
    let (mut out, rest) = (0..=parts.len())
        .rev()
        .find_map(|k| {
            let prefix: PathBuf = parts[..k].iter().collect();
            std::fs::canonicalize(&prefix)
                .ok()
                .map(|real| (real, &parts[k..]))
        })
        .unwrap_or_else(|| (PathBuf::new(), &parts[..]));
    for part in rest {
        match part {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sensaug-outputs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn check(outputs: &[(&str, &Path)]) -> Result<(), String> {
        check_outputs(outputs).map_err(|e| e.to_string())
    }

    #[test]
    fn new_and_regular_files_pass() {
        let d = dir("ok");
        std::fs::write(d.join("old.csv"), b"old").unwrap();
        let (log, stats) = (d.join("old.csv"), d.join("new/sub/stats.json"));
        assert_eq!(check(&[("rig.log", &log), ("rig.stats", &stats)]), Ok(()));
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn devices_fifos_directories_and_links_are_refused_by_name() {
        let d = dir("bad");
        let fifo = d.join("fifo.csv");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        let link = d.join("link.csv");
        std::os::unix::fs::symlink("/dev/null", &link).unwrap();
        let file_link = d.join("file_link.csv");
        std::fs::write(d.join("target.csv"), b"x").unwrap();
        std::os::unix::fs::symlink(d.join("target.csv"), &file_link).unwrap();
        let cases: [(&Path, &str); 6] = [
            (
                Path::new("/dev/full"),
                "cannot write /dev/full: it is a character device, not a",
            ),
            (
                Path::new("/dev/null"),
                "cannot write /dev/null: it is a character device",
            ),
            (&fifo, "it is a FIFO (named pipe)"),
            (
                &link,
                "it is a symbolic link to /dev/null (a character device)",
            ),
            (&file_link, "it is a symbolic link to"),
            (
                &d,
                "it is a directory, not a regular file; give a file path inside it",
            ),
        ];
        for (path, want) in cases {
            let e = check(&[("rig.log", path)]).unwrap_err();
            assert!(e.starts_with("rig.log: ") && e.contains(want), "{e}");
            assert!(e.ends_with(" (--log)"), "{e}");
        }
        // A FIFO where the output is written until the run ends.
        let busy = d.join("busy.csv");
        std::process::Command::new("mkfifo")
            .arg(partial_path(&busy))
            .status()
            .unwrap();
        let e = check(&[("rig.stats", &busy)]).unwrap_err();
        assert!(e.contains("busy.csv.partial (where it is written until the run ends) is a FIFO"));
        assert!(
            e.ends_with("remove it or give another path (--stats)"),
            "{e}"
        );
        // A folder that is a file.
        let e = check(&[("rig.log", &d.join("target.csv/log.csv"))]).unwrap_err();
        assert!(e.contains("is a regular file, not a directory"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn the_same_file_twice_is_refused_however_it_is_spelled() {
        let d = dir("same");
        let a = d.join("x.csv");
        let cases: [PathBuf; 3] = [a.clone(), d.join("sub/../x.csv"), d.join("./x.csv")];
        for b in &cases {
            let e = check(&[("rig.log", &a), ("rig.stats", b)]).unwrap_err();
            assert!(
                e.starts_with("rig.stats: ") && e.contains("the same file as rig.log"),
                "{e}"
            );
        }
        // Through a symbolic link to the folder.
        std::os::unix::fs::symlink(&d, d.join("alias")).unwrap();
        let e = check(&[("rig.log", &a), ("rig.stats", &d.join("alias/x.csv"))]).unwrap_err();
        assert!(e.contains("the same file"), "{e}");
        // One output's temporary file, either way round.
        let e = check(&[("rig.log", &a), ("rig.stats", &d.join("x.csv.partial"))]).unwrap_err();
        assert!(
            e.contains("the same file as rig.log's temporary file"),
            "{e}"
        );
        let e = check(&[
            ("rig.log", &d.join("y.partial")),
            ("rig.stats", &d.join("y")),
        ])
        .unwrap_err();
        assert!(
            e.contains("y's temporary file") && e.contains("the same file as rig.log"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_path_without_a_file_name_is_refused() {
        for p in ["", "out/", ".", "out/.."] {
            let e = check(&[("rig.log", Path::new(p))]).unwrap_err();
            assert!(e.contains("does not end in a file name"), "{p:?}: {e}");
        }
    }
}
