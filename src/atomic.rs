//! Write a file all or nothing, and never over an input.
//!
//! Bytes go to a temporary file in the destination's folder, which is renamed over the destination
//! only on [`AtomicFile::commit`]. Dropped uncommitted (an error, a panic), failing to rename, or
//! interrupted by a signal the CLI handles, the temporary file is removed. A process killed outright
//! leaves its temporary file behind; the next write into that folder removes it (see
//! [`AtomicFile::create`]).
//!
//! Files read as input are registered with [`protect`]; a destination that is one of them (the same
//! path, or the same file through a hard or symbolic link) is refused before anything is written.

use crate::error::{Error, Result};
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, SystemTime};

/// Temporary files in progress, removed by the interrupt handler.
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Files this process reads as input: no output may replace them.
static PROTECTED: Mutex<Vec<Identity>> = Mutex::new(Vec::new());

/// Temporary files of dead processes removed since the last [`take_removed_stale`].
static REMOVED_STALE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// What the temporary file names end with, after the process id: `.<name>.<pid>.strata-tmp`.
const TMP_SUFFIX: &str = "strata-tmp";

/// A temporary file of another process is stale once that process is gone and the file has not
/// changed for this long (a writer on another machine sharing the folder keeps its file fresh).
const STALE_AFTER: Duration = Duration::from_secs(60);

/// A file as the operating system knows it: its canonical path and, on Unix, device and inode.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Identity {
    path: PathBuf,
    #[cfg(unix)]
    inode: (u64, u64),
}

impl Identity {
    /// The identity of an existing file (following links); `None` if it does not exist.
    fn of(path: &Path) -> Option<Identity> {
        let meta = std::fs::metadata(path).ok()?;
        let path = std::fs::canonicalize(path).ok()?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            Some(Identity { path, inode: (meta.dev(), meta.ino()) })
        }
        #[cfg(not(unix))]
        {
            let _ = meta;
            Some(Identity { path })
        }
    }

    /// Whether `other` is this file: the same path, or the same inode while this file's path still
    /// names it (an inode freed by a deleted input may be reused by an unrelated file).
    fn same_file(&self, other: &Identity) -> bool {
        #[cfg(unix)]
        if self.inode == other.inode && Identity::of(&self.path).is_some_and(|now| now.inode == self.inode) {
            return true;
        }
        self.path == other.path
    }
}

/// Register `path` as an input of this process: [`check_output`] and [`AtomicFile::create`] refuse
/// to write over it. A path that does not exist is ignored.
pub fn protect(path: &Path) {
    if let (Some(id), Ok(mut list)) = (Identity::of(path), PROTECTED.lock()) {
        if !list.contains(&id) {
            list.push(id);
        }
    }
}

/// Check that `dest` can be written: not a directory and not a protected input. Commands call it
/// before long work so that a wrong output path fails at once.
pub fn check_output(dest: &Path) -> Result<()> {
    if dest.is_dir() {
        return Err(Error::invalid(dest, None, "is a directory: give a file name to write"));
    }
    if dest.file_name().is_none() {
        return Err(Error::invalid(dest, None, "not a file name"));
    }
    // The output is renamed into place, which would replace a device, pipe or socket (even
    // /dev/null) with a regular file.
    if std::fs::metadata(dest).is_ok_and(|m| !m.is_file()) {
        return Err(Error::invalid(
            dest,
            None,
            "is not a regular file (a device, pipe or socket): strata writes to a temporary file and renames it into place, which would replace it; give a file name",
        ));
    }
    if let Some(id) = Identity::of(dest) {
        let protected = PROTECTED.lock().map(|l| l.iter().any(|p| p.same_file(&id))).unwrap_or(false);
        if protected {
            return Err(Error::invalid(dest, None, "is an input of this command: refusing to write over it (choose another output name)"));
        }
    }
    Ok(())
}

/// Remove every temporary file and folder still in progress. The CLI calls it from its signal
/// handler.
pub fn remove_pending() {
    if let Ok(pending) = PENDING.lock() {
        for p in pending.iter() {
            let _ = std::fs::remove_file(p);
        }
    }
    if let Ok(dirs) = PENDING_DIRS.lock() {
        for d in dirs.iter() {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

/// Temporary folders in use, removed by the interrupt handler.
static PENDING_DIRS: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// A temporary folder for work files, removed with everything in it when dropped (success, error
/// or panic) or when the CLI is interrupted.
pub struct TempDir {
    dir: Option<tempfile::TempDir>,
}

impl TempDir {
    /// A new folder inside `parent`, or the system's temporary folder. Work folders there of
    /// processes that are gone (killed outright) are removed first.
    pub fn create(parent: Option<&Path>) -> Result<TempDir> {
        let parent = parent.map_or_else(std::env::temp_dir, Path::to_path_buf);
        remove_stale_dirs(&parent);
        let prefix = format!("{WORK_PREFIX}{}.", std::process::id());
        let dir = tempfile::Builder::new().prefix(&prefix).tempdir_in(&parent).map_err(|e| Error::io(&parent, e))?;
        if let Ok(mut l) = PENDING_DIRS.lock() {
            l.push(dir.path().to_path_buf());
        }
        Ok(TempDir { dir: Some(dir) })
    }

    pub fn path(&self) -> &Path {
        self.dir.as_ref().map_or(Path::new(""), |d| d.path())
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Some(d) = self.dir.take() {
            if let Ok(mut l) = PENDING_DIRS.lock() {
                l.retain(|p| p != d.path());
            }
            let _ = d.close();
        }
    }
}

/// The temporary files of dead processes that writes of this process removed, since the last call.
pub fn take_removed_stale() -> Vec<PathBuf> {
    REMOVED_STALE.lock().map(|mut l| std::mem::take(&mut *l)).unwrap_or_default()
}

/// Write `dest` all or nothing with `write`, whose I/O errors are reported against `dest`.
pub fn write_file(dest: &Path, write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>) -> Result<()> {
    let mut file = AtomicFile::create(dest)?;
    write(file.writer()).map_err(|e| Error::io(dest, e))?;
    file.commit()
}

/// A file being written under a temporary name.
pub struct AtomicFile {
    dest: PathBuf,
    tmp: PathBuf,
    writer: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Start writing `dest`; nothing appears under that name until [`commit`](Self::commit).
    /// Refuses a directory or a protected input ([`check_output`]). Temporary files that dead
    /// processes left in the same folder are removed first.
    pub fn create(dest: &Path) -> Result<AtomicFile> {
        check_output(dest)?;
        let name = dest.file_name().ok_or_else(|| Error::invalid(dest, None, "not a file name"))?;
        let dir = dest.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        remove_stale(dir);
        let mut tmp_name = std::ffi::OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(".{}.{TMP_SUFFIX}", std::process::id()));
        let tmp = dest.with_file_name(tmp_name);
        // Registered before it exists, so that a signal arriving meanwhile removes it too.
        PENDING.lock().map(|mut p| p.push(tmp.clone())).ok();
        let file = match OpenOptions::new().write(true).create(true).truncate(true).open(&tmp) {
            Ok(f) => f,
            Err(e) => {
                forget_pending(&tmp);
                return Err(Error::io(dest, e));
            }
        };
        Ok(AtomicFile { dest: dest.to_path_buf(), tmp, writer: Some(BufWriter::with_capacity(1 << 20, file)) })
    }

    /// The destination path, for error messages.
    pub fn path(&self) -> &Path {
        &self.dest
    }

    /// The buffered writer.
    pub fn writer(&mut self) -> &mut BufWriter<File> {
        self.writer.as_mut().expect("writer present until commit")
    }

    /// Flush, sync and rename the temporary file over the destination. On any failure the
    /// temporary file is removed and the destination left as it was.
    pub fn commit(mut self) -> Result<()> {
        let writer = self.writer.take().expect("writer present until commit");
        let result = (|| {
            let file = writer.into_inner().map_err(|e| Error::io(&self.dest, e.into_error()))?;
            file.sync_all().map_err(|e| Error::io(&self.dest, e))?;
            drop(file);
            check_output(&self.dest)?;
            std::fs::rename(&self.tmp, &self.dest).map_err(|e| Error::io(&self.dest, e))
        })();
        if result.is_err() {
            let _ = std::fs::remove_file(&self.tmp);
        }
        forget_pending(&self.tmp);
        result
    }
}

fn forget_pending(tmp: &Path) {
    if let Ok(mut p) = PENDING.lock() {
        p.retain(|x| x != tmp);
    }
}

/// The process id in a temporary file name of ours, `.<name>.<pid>.strata-tmp`.
fn tmp_pid(file_name: &str) -> Option<u32> {
    let rest = file_name.strip_prefix('.')?.strip_suffix(TMP_SUFFIX)?.strip_suffix('.')?;
    let (_, pid) = rest.rsplit_once('.')?;
    pid.parse().ok()
}

/// Whether process `pid` is running on this machine.
fn alive(pid: u32) -> bool {
    #[cfg(unix)]
    {
        let Ok(pid) = libc::pid_t::try_from(pid) else { return false };
        // Signal 0 checks existence; EPERM means it exists under another user.
        let r = unsafe { libc::kill(pid, 0) };
        r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        true
    }
}

/// What work folders' names start with, before the process id and a random part.
const WORK_PREFIX: &str = ".strata-work.";

/// A work folder of a process that is gone is stale once nothing in it has changed for this long
/// (longer than for a file: a folder shared by machines may belong to a live process elsewhere).
const STALE_DIR_AFTER: Duration = Duration::from_secs(3600);

/// Remove work folders in `dir` of processes that are gone, once nothing in them changed for
/// [`STALE_DIR_AFTER`].
fn remove_stale_dirs(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let now = SystemTime::now();
    let idle = |p: &Path| -> Option<Duration> {
        let changed = |m: std::fs::Metadata| m.modified().ok().and_then(|t| now.duration_since(t).ok());
        let mut least = changed(std::fs::metadata(p).ok()?)?;
        for e in std::fs::read_dir(p).ok()?.flatten() {
            least = least.min(changed(e.metadata().ok()?)?);
        }
        Some(least)
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let pid = name
            .to_str()
            .and_then(|n| n.strip_prefix(WORK_PREFIX))
            .and_then(|r| r.split_once('.'))
            .and_then(|(p, _)| p.parse::<u32>().ok());
        let Some(pid) = pid else { continue };
        if pid == std::process::id() || alive(pid) || !entry.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        let path = entry.path();
        if idle(&path).is_some_and(|d| d >= STALE_DIR_AFTER) && std::fs::remove_dir_all(&path).is_ok() {
            REMOVED_STALE.lock().map(|mut l| l.push(path)).ok();
        }
    }
}

/// Remove temporary files in `dir` left by processes that are gone (killed before they could
/// clean up), once untouched for [`STALE_AFTER`].
fn remove_stale(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let now = SystemTime::now();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(tmp_pid) else { continue };
        if pid == std::process::id() || alive(pid) {
            continue;
        }
        let idle = entry.metadata().ok().and_then(|m| m.modified().ok()).and_then(|t| now.duration_since(t).ok());
        if idle.is_some_and(|d| d >= STALE_AFTER) && entry.file_type().is_ok_and(|t| t.is_file()) {
            let path = entry.path();
            if std::fs::remove_file(&path).is_ok() {
                REMOVED_STALE.lock().map(|mut l| l.push(path)).ok();
            }
        }
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.writer().write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.writer().flush()
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.writer.take().is_some() {
            let _ = std::fs::remove_file(&self.tmp);
            forget_pending(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("strata-atomic-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn uncommitted_file_leaves_nothing() {
        let dir = scratch("commit");
        let dest = dir.join("out.bin");
        {
            let mut f = AtomicFile::create(&dest).unwrap();
            f.write_all(b"partial").unwrap();
        }
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        let mut f = AtomicFile::create(&dest).unwrap();
        f.write_all(b"whole").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read(&dest).unwrap(), b"whole");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_directory_or_a_protected_input_is_refused() {
        let dir = scratch("protect");
        let err = AtomicFile::create(&dir).err().expect("a directory is refused").to_string();
        assert!(err.contains("directory"), "{err}");
        let input = dir.join("in.obj");
        std::fs::write(&input, b"v 0 0 0\n").unwrap();
        protect(&input);
        let err = AtomicFile::create(&input).err().expect("an input is refused").to_string();
        assert!(err.contains("input"), "{err}");
        #[cfg(unix)]
        {
            let link = dir.join("link.obj");
            std::os::unix::fs::symlink(&input, &link).unwrap();
            assert!(AtomicFile::create(&link).is_err());
            let hard = dir.join("hard.obj");
            std::fs::hard_link(&input, &hard).unwrap();
            assert!(AtomicFile::create(&hard).is_err());
        }
        assert_eq!(std::fs::read(&input).unwrap(), b"v 0 0 0\n");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_device_is_refused_not_replaced() {
        let null = Path::new("/dev/null");
        if !std::fs::metadata(null).is_ok_and(|m| !m.is_file()) {
            return;
        }
        let err = AtomicFile::create(null).err().expect("a device is refused").to_string();
        assert!(err.contains("not a regular file"), "{err}");
        assert!(!std::fs::metadata(null).unwrap().is_file(), "/dev/null is still a device");
    }

    #[test]
    fn stale_temporaries_of_dead_processes_are_removed() {
        assert_eq!(tmp_pid(".out.strata.123.strata-tmp"), Some(123));
        assert_eq!(tmp_pid("out.strata.123.strata-tmp"), None);
        assert_eq!(tmp_pid(".out.123.tmp"), None);
        let dir = scratch("stale");
        // No process has id 2^31 - 2 (Linux caps ids at 2^22).
        let dead = dir.join(".a.strata.2147483646.strata-tmp");
        let fresh_dead = dir.join(".b.strata.2147483645.strata-tmp");
        let ours_alive = dir.join(format!(".c.strata.{}.strata-tmp", std::process::id()));
        for p in [&dead, &fresh_dead, &ours_alive] {
            std::fs::write(p, b"x").unwrap();
        }
        let old = SystemTime::now() - 2 * STALE_AFTER;
        File::options().write(true).open(&dead).unwrap().set_modified(old).unwrap();
        File::options().write(true).open(&ours_alive).unwrap().set_modified(old).unwrap();
        AtomicFile::create(&dir.join("new.bin")).unwrap().commit().unwrap();
        assert!(!dead.exists() && fresh_dead.exists() && ours_alive.exists());
        assert!(take_removed_stale().contains(&dead));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
