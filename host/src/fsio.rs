//! Writing files so that a reader (or a crash) never sees half of one: everything the host writes
//! goes to a temporary file in the same folder, is flushed to disk, renamed into place, and the
//! folder is flushed so the rename itself survives a power cut.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A fixed hidden name beside `path`, unique per process (for a symlink renamed into place).
pub fn temp_name(path: &Path) -> PathBuf {
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{file_name}.tmp-{}", std::process::id()))
}

/// The folder `path` is in (`.` for a bare file name).
pub fn parent_dir(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Flush a folder's entries (new, renamed, removed files) to disk.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir)?.sync_all()
}

/// Write through `fill` into a temporary file beside `path`, fsync it, rename it to `path` and
/// fsync the folder. On any error the temporary file is removed and `path` is left as it was.
pub fn write_atomically<E>(path: &Path, fill: impl FnOnce(&Path) -> Result<(), E>) -> Result<(), AtomicWriteError<E>> {
    let dir = parent_dir(path);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(".tmp")
        // Created as `File::create` would (mode 0666 less the umask), not 0600.
        .permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666))
        .tempfile_in(dir)
        .map_err(AtomicWriteError::Io)?;
    fill(tmp.path()).map_err(AtomicWriteError::Fill)?;
    // `fill` may have written through a handle of its own: sync the file it left at that name.
    File::open(tmp.path())
        .and_then(|f| f.sync_all())
        .map_err(AtomicWriteError::Io)?;
    tmp.persist(path).map_err(|e| AtomicWriteError::Io(e.error))?;
    sync_dir(dir).map_err(AtomicWriteError::Io)
}

/// [`write_atomically`] for bytes already in memory.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomically(path, |tmp| File::create(tmp).and_then(|mut f| f.write_all(bytes))).map_err(|e| match e {
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
    use std::os::unix::fs::PermissionsExt;

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

    /// An atomically written file gets the permissions a plain `File::create` gives.
    #[test]
    fn the_written_file_has_the_usual_permissions() {
        let dir = tempfile::tempdir().unwrap();
        let plain = dir.path().join("plain");
        File::create(&plain).unwrap();
        let atomic = dir.path().join("atomic");
        write_bytes_atomically(&atomic, b"x").unwrap();
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&atomic), mode(&plain));
    }

    #[test]
    fn a_missing_folder_cannot_be_synced_or_written_into() {
        let dir = tempfile::tempdir().unwrap();
        let gone = dir.path().join("gone");
        assert!(sync_dir(&gone).is_err());
        assert!(write_bytes_atomically(&gone.join("f"), b"x").is_err());
        assert_eq!(parent_dir(Path::new("f")), Path::new("."));
    }
}
