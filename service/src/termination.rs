//! SIGINT, SIGTERM and SIGHUP as a file descriptor that the I/O thread's WaitSet sleeps on. Each
//! stops the daemon cleanly: SIGHUP comes when the terminal it was started from closes, and
//! would otherwise end it at once, with requests unanswered.
//!
//! With iceoryx2's own handling, a handler writes the last signal into one process-wide slot,
//! and the slot is also read and reset by other code: every node's termination check consumes
//! it, and iceoryx2 resets it before it zeroes a new shared-memory segment. A daemon was seen to
//! serve on after a SIGTERM (twice in about 220 stops; not reproduced on demand), which a
//! supervisor can only end with SIGKILL. Instead the daemon blocks the three signals in every thread
//! and reads them from a `signalfd`: a blocked signal stays pending in the kernel until this
//! module reads it, whatever the threads are doing when it arrives.

use std::cell::Cell;
use std::os::fd::RawFd;

use iceoryx2::prelude::{FileDescriptor, FileDescriptorBased, SynchronousMultiplexing};

/// The signals that stop the daemon.
fn termination_set() -> libc::sigset_t {
    // SAFETY: sigemptyset/sigaddset initialise and fill a sigset_t local to this function.
    unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        libc::sigaddset(&mut set, libc::SIGINT);
        libc::sigaddset(&mut set, libc::SIGTERM);
        libc::sigaddset(&mut set, libc::SIGHUP);
        set
    }
}

/// Blocks the termination signals (SIGINT, SIGTERM, SIGHUP) in the calling thread; threads it
/// starts afterwards inherit the mask. Blocked, they wait in the kernel for
/// [`TerminationSignals::requested`].
pub fn block_termination_signals() {
    let set = termination_set();
    // SAFETY: pthread_sigmask with a valid set and no old-set output.
    unsafe {
        libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut());
    }
}

/// A `signalfd` for SIGINT, SIGTERM and SIGHUP. Create it on the I/O thread before any other
/// thread of the daemon starts, so that every thread blocks them.
#[derive(Debug)]
pub struct TerminationSignals {
    fd: FileDescriptor,
    raw: RawFd,
    requested: Cell<bool>,
}

impl TerminationSignals {
    /// Blocks the termination signals in the calling thread and opens a non-blocking `signalfd`
    /// for them.
    pub fn new() -> std::io::Result<TerminationSignals> {
        block_termination_signals();
        let set = termination_set();
        // SAFETY: signalfd with a valid set; -1 asks for a new descriptor.
        let raw = unsafe { libc::signalfd(-1, &set, libc::SFD_NONBLOCK | libc::SFD_CLOEXEC) };
        if raw < 0 {
            return Err(std::io::Error::last_os_error());
        }
        let fd = FileDescriptor::new(raw)
            .ok_or_else(|| std::io::Error::other("signalfd returned an unusable descriptor"))?;
        Ok(TerminationSignals {
            fd,
            raw,
            requested: Cell::new(false),
        })
    }

    /// Whether SIGINT, SIGTERM or SIGHUP has arrived (since this was created): reads what is
    /// pending, and stays true once it is.
    pub fn requested(&self) -> bool {
        let mut info: libc::signalfd_siginfo = unsafe { std::mem::zeroed() };
        let size = std::mem::size_of::<libc::signalfd_siginfo>();
        loop {
            // SAFETY: reads one signalfd_siginfo into a local of exactly that size from a
            // non-blocking signalfd this struct owns.
            let n = unsafe {
                libc::read(
                    self.raw,
                    (&mut info as *mut libc::signalfd_siginfo).cast(),
                    size,
                )
            };
            if n != size as isize {
                break;
            }
            tracing::info!(signal = info.ssi_signo, "termination requested");
            self.requested.set(true);
        }
        self.requested.get()
    }
}

impl FileDescriptorBased for TerminationSignals {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.fd
    }
}

impl SynchronousMultiplexing for TerminationSignals {}

#[cfg(test)]
mod tests {
    use super::*;

    /// A SIGTERM sent to a thread that holds the signalfd is seen, however long it has been
    /// pending, and stays seen.
    #[test]
    fn a_pending_sigterm_is_read_once_and_remembered() {
        // A thread of its own: the test harness's threads keep their masks.
        std::thread::spawn(|| {
            let t = TerminationSignals::new().unwrap();
            assert!(!t.requested());
            // SAFETY: raise sends SIGTERM to this thread, where it is blocked, so it stays
            // pending instead of ending the test process.
            assert_eq!(unsafe { libc::raise(libc::SIGTERM) }, 0);
            assert!(t.requested());
            assert!(t.requested(), "a request is remembered once read");
        })
        .join()
        .unwrap();
    }

    /// A SIGTERM that arrives while iceoryx2 sets up shared memory (which resets iceoryx2's
    /// last-signal slot) is still there when the I/O thread looks.
    #[test]
    fn a_sigterm_survives_the_creation_of_shared_memory() {
        use iceoryx2::prelude::*;
        std::thread::spawn(|| {
            let t = TerminationSignals::new().unwrap();
            // SAFETY: as above, SIGTERM to this thread, where it is blocked.
            assert_eq!(unsafe { libc::raise(libc::SIGTERM) }, 0);
            let node = NodeBuilder::new()
                .signal_handling_mode(SignalHandlingMode::Disabled)
                .create::<ipc::Service>()
                .unwrap();
            let name = format!("ppfd-termination-test-{}", std::process::id());
            let service = node
                .service_builder(&ServiceName::new(&name).unwrap())
                .publish_subscribe::<[u8]>()
                .open_or_create()
                .unwrap();
            let publisher = service
                .publisher_builder()
                .initial_max_slice_len(4096)
                .create()
                .unwrap();
            drop(publisher);
            assert!(
                t.requested(),
                "the SIGTERM is still pending after shared memory was made"
            );
        })
        .join()
        .unwrap();
    }
}
