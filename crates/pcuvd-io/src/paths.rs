//! What a path names, said before it is opened: a folder, a named pipe (opening one for reading
//! waits for a writer, forever), a device, a broken symbolic link or a loop of them each get a
//! message that says what the path is, never "does not exist" or a hang.

use std::path::Path;

use crate::error::IoError;

/// Checks that `path` names a regular file (following symbolic links), without opening it; the
/// error says what the path is instead.
pub fn check_regular_file(path: &Path) -> Result<(), IoError> {
    let not_a_file = |what: String| IoError::NotAFile {
        path: path.to_path_buf(),
        what,
    };
    match std::fs::metadata(path) {
        Ok(meta) => {
            let kind = meta.file_type();
            if kind.is_file() {
                return Ok(());
            }
            Err(not_a_file(describe(&kind).to_string()))
        }
        Err(e) => match std::fs::symlink_metadata(path) {
            // The link itself exists: its target does not, or the links go round in a loop.
            Ok(link) if link.file_type().is_symlink() => {
                let target = std::fs::read_link(path)
                    .map(|t| t.display().to_string())
                    .unwrap_or_else(|_| "?".into());
                if e.kind() == std::io::ErrorKind::NotFound {
                    Err(not_a_file(format!(
                        "a symbolic link to {target}, which does not exist"
                    )))
                } else if e.raw_os_error() == Some(LOOP_ERRNO) {
                    Err(not_a_file(format!(
                        "a symbolic link to {target} in a loop of symbolic links"
                    )))
                } else {
                    Err(IoError::io(path, "read", e))
                }
            }
            _ if e.kind() == std::io::ErrorKind::NotFound => Err(IoError::NotFound {
                path: path.to_path_buf(),
            }),
            _ => Err(IoError::io(path, "read", e)),
        },
    }
}

/// What `path` is when it exists but is not a regular file ("a folder", "a named pipe (FIFO)",
/// "a symbolic link to X in a loop of symbolic links", ...); `None` for a regular file or nothing.
pub fn what_is(path: &Path) -> Option<String> {
    match check_regular_file(path) {
        Err(IoError::NotAFile { what, .. }) => Some(what),
        _ => None,
    }
}

/// ELOOP: too many levels of symbolic links (Linux and the BSDs agree on 40 and 62 resp.).
#[cfg(target_os = "linux")]
const LOOP_ERRNO: i32 = 40;
#[cfg(not(target_os = "linux"))]
const LOOP_ERRNO: i32 = 62;

/// What a path that is not a regular file is, in words.
fn describe(kind: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_fifo() {
            return "a named pipe (FIFO)";
        }
        if kind.is_socket() {
            return "a socket";
        }
        if kind.is_block_device() || kind.is_char_device() {
            return "a device";
        }
    }
    if kind.is_dir() {
        "a folder"
    } else {
        "not a regular file"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_kind_of_path_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("rec.npy");
        std::fs::write(&file, b"x").unwrap();
        check_regular_file(&file).unwrap();
        let said = |p: &Path| check_regular_file(p).unwrap_err().to_string();
        assert!(said(dir.path()).contains("is a folder, not a file"));
        assert!(said(&dir.path().join("nope.npy")).contains("does not exist"));
        #[cfg(unix)]
        {
            let (a, b) = (dir.path().join("a"), dir.path().join("b"));
            std::os::unix::fs::symlink(&b, &a).unwrap();
            std::os::unix::fs::symlink(&a, &b).unwrap();
            assert!(said(&a).contains("loop of symbolic links"), "{}", said(&a));
            let broken = dir.path().join("broken");
            std::os::unix::fs::symlink(dir.path().join("gone"), &broken).unwrap();
            assert!(said(&broken).contains("which does not exist"));
            let fifo = dir.path().join("fifo");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if made.is_ok_and(|s| s.success()) {
                assert!(said(&fifo).contains("named pipe"), "{}", said(&fifo));
            }
        }
    }
}
