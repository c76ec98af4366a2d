//! All-or-nothing output: write to a temporary file beside the target, then rename.

use crate::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// The temporary name used while `path` is being written.
pub fn temp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(format!(".tmp-{}", std::process::id()));
    path.with_file_name(name)
}

/// Refuses, before any work is done, an output file `path` that is a directory or whose directory
/// does not exist (a mistyped `-o`): the write at the end would fail only after the encode or
/// training.
///
/// # Errors
/// [`Error::input`] naming `path`.
pub fn check_output_file(path: &Path) -> Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !dir.is_dir() {
        Err(Error::input(path, format!("cannot write: directory {} does not exist", dir.display())))
    } else if path.is_dir() {
        Err(Error::input(path, "cannot write: is a directory"))
    } else {
        Ok(())
    }
}

/// Writes `path` through `write`; on any error the target is left untouched and the temporary removed.
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>) -> Result<()> {
    let tmp = temp_path(path);
    let result = (|| {
        let mut w = BufWriter::new(File::create(&tmp)?);
        write(&mut w)?;
        w.flush()?;
        drop(w);
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::failure(path, format!("cannot write: {e}"))
    })
}

/// Writes a byte buffer atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// Fills a fresh temporary directory beside `dir` through `fill`, then moves its files into `dir`
/// (created if needed; same-named files are replaced). On error nothing reaches `dir` and the
/// temporary directory is removed.
pub fn write_dir_atomic(dir: &Path, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let tmp = temp_path(dir);
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(|e| Error::failure(&tmp, format!("cannot create directory: {e}")))?;
    let result = fill(&tmp).and_then(|()| {
        if !dir.exists() {
            return std::fs::rename(&tmp, dir).map_err(|e| Error::failure(dir, format!("cannot create: {e}")));
        }
        if !dir.is_dir() {
            return Err(Error::input(dir, "exists and is not a directory"));
        }
        move_tree(&tmp, dir).map_err(|e| Error::failure(dir, format!("cannot write: {e}")))
    });
    let _ = std::fs::remove_dir_all(&tmp);
    result
}

fn move_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    for entry in std::fs::read_dir(from)? {
        let entry = entry?;
        let dst = to.join(entry.file_name());
        if entry.file_type()?.is_dir() && dst.is_dir() {
            move_tree(&entry.path(), &dst)?;
        } else {
            std::fs::rename(entry.path(), &dst)?;
        }
    }
    Ok(())
}
