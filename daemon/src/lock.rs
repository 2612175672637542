//! One daemon per team: a daemon holds an exclusive lock on a file named
//! after each team's plan service while it serves it. The kernel releases
//! the lock when the process ends, however it ends, so a daemon killed with
//! SIGKILL does not block its successor. A clean exit also removes the file;
//! a daemon that locked a file another removed meanwhile (its inode is no
//! longer the path's) locks the path's new file instead.

use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::path::PathBuf;

use thiserror::Error;

/// Why a team could not be locked.
#[derive(Debug, Error)]
pub enum LockError {
    /// Another live daemon serves the team.
    #[error("LockError::Served: team {team:?} is already served on {service} by another daemon (lock {path})")]
    Served {
        /// The team.
        team: String,
        /// Its plan service.
        service: String,
        /// The lock file.
        path: String,
    },
    /// The lock file could not be opened.
    #[error("LockError::Io: cannot open the lock file {path}: {source}")]
    Io {
        /// The lock file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
}

/// The lock on one team's services, held while the value lives; dropping
/// it removes the lock file.
#[derive(Debug)]
pub struct TeamLock {
    file: File,
    path: PathBuf,
}

/// Tries to lock the file at `path` again after it was replaced under a
/// lock this many times.
const RETRIES: usize = 8;

impl TeamLock {
    /// Locks `prefix/team`, or says which daemon-held service is in the way.
    pub fn acquire(prefix: &str, team: &str) -> Result<Self, LockError> {
        let service = format!("{prefix}/{team}/plan");
        let name: String =
            service.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '.' }).collect();
        let path: PathBuf = std::env::temp_dir().join(format!("flowopt-{name}.lock"));
        let shown = path.display().to_string();
        let io = |source| LockError::Io { path: shown.clone(), source };
        for _ in 0..RETRIES {
            let file = OpenOptions::new().create(true).truncate(false).write(true).open(&path).map_err(io)?;
            // SAFETY: flock(2) on a descriptor this process owns.
            let locked = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0;
            if !locked {
                return Err(LockError::Served { team: team.to_string(), service, path: shown });
            }
            // The previous holder may have removed the file between our
            // open and our lock: then the lock is on a file no one else
            // will open, and the path's file is the one to lock.
            if same_file(&file, &path) {
                return Ok(Self { file, path });
            }
        }
        Err(io(std::io::Error::other("the lock file kept being replaced")))
    }
}

/// Whether `file` is the file now at `path`.
fn same_file(file: &File, path: &std::path::Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

impl Drop for TeamLock {
    fn drop(&mut self) {
        // Removed while still locked, so no other daemon can be holding it.
        if same_file(&self.file, &self.path) {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_on_a_team_is_refused_until_the_first_is_dropped() {
        let prefix = format!("flowopt-lock-test-{}", std::process::id());
        let first = TeamLock::acquire(&prefix, "a").unwrap();
        let second = TeamLock::acquire(&prefix, "a").unwrap_err();
        assert!(second.to_string().contains(&format!("{prefix}/a/plan")), "{second}");
        let _other_team = TeamLock::acquire(&prefix, "b").unwrap();
        let path = first.path.clone();
        assert!(path.exists());
        drop(first);
        assert!(!path.exists(), "a clean release removes the lock file");
        let _again = TeamLock::acquire(&prefix, "a").unwrap();
    }
}
