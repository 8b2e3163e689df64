//! One pseudo-terminal in raw mode behind a symlink, and the I/O error
//! helpers of the serving code.

use crate::fault::SimError;
use nix::fcntl::{fcntl, FcntlArg, FdFlag, OFlag};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::termios::{cfmakeraw, tcflush, tcgetattr, tcsetattr, FlushArg, SetArg};
use std::fs::File;
use std::io;
use std::os::fd::{AsFd, AsRawFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

pub(super) fn io_err(context: impl Into<String>) -> impl FnOnce(io::Error) -> SimError {
    let context = context.into();
    move |source| SimError::Io { context, source }
}

pub(super) fn nix_err(context: impl Into<String>) -> impl FnOnce(nix::Error) -> SimError {
    let context = context.into();
    move |e| SimError::Io {
        context,
        source: io::Error::from(e),
    }
}

/// One open pty. Dropping it closes the master, which hangs up the client.
#[derive(Debug)]
pub(super) struct Pty {
    pub(super) master: File,
    pub(super) slave_path: PathBuf,
    /// Whether a client had the slave open at the last look.
    pub(super) connected: bool,
}

impl Pty {
    /// Opens a raw, non-blocking pty and points `link` at its slave. The
    /// slave is configured and closed again: the settings stay with the pty.
    ///
    /// Both ends are close-on-exec (`openpty` does not set it): a process
    /// spawned by the program that serves in process (another test of the
    /// same test binary, say) must not inherit the master, or dropping the
    /// line would no longer hang up its client, nor the slave, which would
    /// keep the line looking connected.
    pub(super) fn open(link: &Path) -> Result<Pty, SimError> {
        let pair = nix::pty::openpty(None, None).map_err(nix_err("openpty"))?;
        for fd in [pair.master.as_raw_fd(), pair.slave.as_raw_fd()] {
            fcntl(fd, FcntlArg::F_SETFD(FdFlag::FD_CLOEXEC))
                .map_err(nix_err("set pty close-on-exec"))?;
        }
        let mut t = tcgetattr(pair.slave.as_fd()).map_err(nix_err("tcgetattr on pty slave"))?;
        cfmakeraw(&mut t);
        tcsetattr(pair.slave.as_fd(), SetArg::TCSANOW, &t)
            .map_err(nix_err("tcsetattr (raw mode) on pty slave"))?;
        fcntl(
            pair.master.as_raw_fd(),
            FcntlArg::F_SETFL(OFlag::O_NONBLOCK),
        )
        .map_err(nix_err("set pty master non-blocking"))?;
        let slave_path =
            nix::unistd::ttyname(pair.slave.as_fd()).map_err(nix_err("ttyname of pty slave"))?;
        relink(link, &slave_path)?;
        Ok(Pty {
            master: File::from(pair.master),
            slave_path,
            connected: false,
        })
    }

    /// Polls the master for up to `wait`: returns (readable, client present).
    pub(super) fn wait(&self, wait: Duration) -> (bool, bool) {
        let ms = u16::try_from(wait.as_millis()).unwrap_or(u16::MAX);
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(n) if n > 0 => {
                let r = fds[0].revents().unwrap_or(PollFlags::empty());
                (
                    r.intersects(PollFlags::POLLIN),
                    !r.intersects(PollFlags::POLLHUP),
                )
            }
            Ok(_) => (false, true),
            Err(_) => (false, false),
        }
    }

    /// Discards the answers a client left unread. They sit in the master's
    /// output and the slave's line discipline; only a flush through the
    /// slave side reaches the latter. The other direction is left alone: a
    /// client that has just opened the port may already have sent its first
    /// request.
    pub(super) fn flush(&self) {
        use std::os::unix::fs::OpenOptionsExt;
        let _ = tcflush(self.master.as_fd(), FlushArg::TCOFLUSH);
        let slave = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags((OFlag::O_NOCTTY | OFlag::O_NONBLOCK).bits())
            .open(&self.slave_path);
        if let Ok(f) = slave {
            let _ = tcflush(f.as_fd(), FlushArg::TCIFLUSH);
        }
    }
}

/// Points `link` at `target`, replacing any old link atomically (a client
/// never sees the link missing during a restore).
fn relink(link: &Path, target: &Path) -> Result<(), SimError> {
    let name = link
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = link.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)
        .map_err(io_err(format!("create symlink {}", tmp.display())))?;
    std::fs::rename(&tmp, link).map_err(io_err(format!("rename symlink to {}", link.display())))
}
