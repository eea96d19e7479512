//! Writing files so that a reader (or a crash) never sees half of one: everything the host writes
//! goes to a temporary name in the same folder, is flushed to disk, and is renamed into place.

use std::io::Write;
use std::path::{Path, PathBuf};

/// The temporary name `path` is written under: hidden, in the same folder (so the rename is atomic
/// on one file system), and unique per process.
pub fn temp_name(path: &Path) -> PathBuf {
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{file_name}.tmp-{}", std::process::id()))
}

/// Write through `fill` into a temporary file beside `path`, fsync it and rename it to `path`.
/// On any error the temporary file is removed and `path` is left as it was.
pub fn write_atomically<E>(path: &Path, fill: impl FnOnce(&Path) -> Result<(), E>) -> Result<(), AtomicWriteError<E>> {
    let tmp = temp_name(path);
    let result = fill(&tmp).map_err(AtomicWriteError::Fill).and_then(|()| {
        std::fs::File::open(&tmp)
            .and_then(|f| f.sync_all())
            .and_then(|()| std::fs::rename(&tmp, path))
            .map_err(AtomicWriteError::Io)
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// [`write_atomically`] for bytes already in memory.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomically(path, |tmp| {
        std::fs::File::create(tmp).and_then(|mut f| f.write_all(bytes))
    })
    .map_err(|e| match e {
        AtomicWriteError::Fill(e) | AtomicWriteError::Io(e) => e,
    })
}

/// Why an atomic write failed: the caller's writer, or the flush and rename after it.
#[derive(Debug)]
pub enum AtomicWriteError<E> {
    Fill(E),
    Io(std::io::Error),
}

impl<E: std::fmt::Display> std::fmt::Display for AtomicWriteError<E> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AtomicWriteError::Fill(e) => e.fmt(f),
            AtomicWriteError::Io(e) => e.fmt(f),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_neither_the_target_nor_the_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        let err = write_atomically(&path, |tmp| {
            std::fs::write(tmp, b"half").unwrap();
            Err::<(), _>("writer failed")
        })
        .unwrap_err();
        assert!(matches!(err, AtomicWriteError::Fill("writer failed")));
        assert!(!path.exists());
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "temporary left behind"
        );
    }

    #[test]
    fn a_successful_write_replaces_the_old_file_whole() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        std::fs::write(&path, b"old contents").unwrap();
        write_bytes_atomically(&path, b"new").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
