//! Reading input files: each is opened once and checked on the open handle, never by its path
//! again, so a path swapped for a symlink to a device between a check and the read reads
//! nothing; and every read stops at a stated size ([`Limit`]).

use std::fs::File;
use std::io::Read;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

use crate::{Error, Result};

/// The largest file one read takes, with what it is and how to raise it, for the refusal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limit {
    /// What the file is ("mesh file").
    pub what: &'static str,
    /// Bytes read at most.
    pub max_bytes: u64,
    /// How a caller raises the limit (the setting or constant to change).
    pub raise: &'static str,
}

impl Limit {
    /// Refuses a file of `bytes` bytes when it is beyond the limit, naming the limit and how to
    /// raise it.
    pub fn check(&self, path: &Path, bytes: u64) -> Result<()> {
        if bytes <= self.max_bytes {
            return Ok(());
        }
        Err(Error::File {
            path: path.to_path_buf(),
            reason: format!(
                "{bytes} bytes is larger than the largest {} read, {} bytes ({})",
                self.what, self.max_bytes, self.raise
            ),
        })
    }
}

/// Opens `path` for reading and checks the open file: a folder, a FIFO, a socket or a device is
/// refused. Opened without blocking, so a FIFO with no writer is refused at once instead of
/// waiting. Returns the file and its length.
pub fn open_regular(path: &Path) -> Result<(File, u64)> {
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    let kind = if meta.is_dir() {
        Some("a folder")
    } else if !meta.is_file() {
        Some("not a regular file (a FIFO, socket or device)")
    } else {
        None
    };
    if let Some(kind) = kind {
        return Err(Error::File {
            path: path.to_path_buf(),
            reason: format!("is {kind}: give a regular file"),
        });
    }
    Ok((file, meta.len()))
}

/// Reads the regular file at `path` whole, refusing it when it holds more than `limit` (also
/// when it grows past the limit while it is read).
pub fn read_bounded(path: &Path, limit: &Limit) -> Result<Vec<u8>> {
    let (file, len) = open_regular(path)?;
    limit.check(path, len)?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(limit.max_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
    limit.check(path, bytes.len() as u64)?;
    Ok(bytes)
}

/// [`read_bounded`] of a text file; refuses bytes that are not UTF-8.
pub fn read_text_bounded(path: &Path, limit: &Limit) -> Result<String> {
    String::from_utf8(read_bounded(path, limit)?).map_err(|e| Error::File {
        path: path.to_path_buf(),
        reason: format!("is not UTF-8 text: {e}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: Limit = Limit {
        what: "test file",
        max_bytes: 8,
        raise: "raise SMALL",
    };

    fn scratch(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("ppfd-file-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn special_files_are_refused_on_the_open_handle() {
        let dir = scratch("special");
        let link = dir.join("zero.ply");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        let m = read_bounded(&link, &SMALL).unwrap_err().to_string();
        assert!(m.contains("not a regular file"), "{m}");
        let fifo = dir.join("fifo.ply");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        // Without a writer: refused at once, not waited on.
        let m = read_bounded(&fifo, &SMALL).unwrap_err().to_string();
        assert!(m.contains("not a regular file"), "{m}");
        let m = read_bounded(&dir, &SMALL).unwrap_err().to_string();
        assert!(m.contains("a folder"), "{m}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_file_beyond_its_limit_is_refused_naming_the_limit() {
        let dir = scratch("limit");
        let path = dir.join("f");
        std::fs::write(&path, b"12345678").unwrap();
        assert_eq!(read_bounded(&path, &SMALL).unwrap(), b"12345678");
        std::fs::write(&path, b"123456789").unwrap();
        let m = read_bounded(&path, &SMALL).unwrap_err().to_string();
        assert!(
            m.contains("9 bytes") && m.contains("8 bytes") && m.contains("raise SMALL"),
            "{m}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
