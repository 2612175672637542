//! One daemon per team: a daemon holds an exclusive lock on a file named
//! after each team's plan service while it serves it. The kernel releases
//! the lock when the process ends, however it ends, so a daemon killed with
//! SIGKILL does not block its successor.

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

/// The lock on one team's services, held while the value lives.
#[derive(Debug)]
pub struct TeamLock {
    _file: File,
}

impl TeamLock {
    /// Locks `prefix/team`, or says which daemon-held service is in the way.
    pub fn acquire(prefix: &str, team: &str) -> Result<Self, LockError> {
        let service = format!("{prefix}/{team}/plan");
        let name: String =
            service.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '.' }).collect();
        let path: PathBuf = std::env::temp_dir().join(format!("flowopt-{name}.lock"));
        let shown = path.display().to_string();
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .map_err(|source| LockError::Io { path: shown.clone(), source })?;
        // SAFETY: flock(2) on a descriptor this process owns.
        let locked = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0;
        if !locked {
            return Err(LockError::Served { team: team.to_string(), service, path: shown });
        }
        Ok(Self { _file: file })
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
        drop(first);
        let _again = TeamLock::acquire(&prefix, "a").unwrap();
    }
}
