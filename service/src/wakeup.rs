//! Wakes the I/O thread from a worker: an `eventfd` the WaitSet watches beside the iceoryx2
//! listeners.

use std::os::fd::RawFd;

use iceoryx2::prelude::{FileDescriptor, FileDescriptorBased, SynchronousMultiplexing};

/// An `eventfd`: [`Signaller::signal`] from any thread, [`Wakeup::drain`] on the I/O thread.
#[derive(Debug)]
pub struct Wakeup {
    fd: FileDescriptor,
    raw: RawFd,
}

impl Wakeup {
    /// Creates a non-blocking eventfd.
    pub fn new() -> std::io::Result<Wakeup> {
        // SAFETY: eventfd has no memory preconditions.
        let raw = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if raw < 0 {
            return Err(std::io::Error::last_os_error());
        }
        let fd = FileDescriptor::new(raw)
            .ok_or_else(|| std::io::Error::other("eventfd returned an unusable descriptor"))?;
        Ok(Wakeup { fd, raw })
    }

    /// A handle that worker threads can signal with.
    pub fn signaller(&self) -> Signaller {
        Signaller { raw: self.raw }
    }

    /// Consumes pending signals; returns whether there were any.
    pub fn drain(&self) -> bool {
        let mut value: u64 = 0;
        // SAFETY: reads 8 bytes into a u64 from a non-blocking eventfd this struct owns.
        let n = unsafe { libc::read(self.raw, (&mut value as *mut u64).cast(), 8) };
        n == 8
    }
}

impl FileDescriptorBased for Wakeup {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.fd
    }
}

impl SynchronousMultiplexing for Wakeup {}

/// Signals a [`Wakeup`]. Valid while the `Wakeup` lives: the daemon joins every worker job
/// before dropping it.
#[derive(Debug, Clone, Copy)]
pub struct Signaller {
    raw: RawFd,
}

impl Signaller {
    /// Wakes the I/O thread.
    pub fn signal(&self) {
        let one: u64 = 1;
        // SAFETY: writes 8 bytes from a u64 to an eventfd; failure (counter overflow) only
        // means a wake-up is already pending.
        unsafe { libc::write(self.raw, (&one as *const u64).cast(), 8) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_signal_is_seen_once() {
        let w = Wakeup::new().unwrap();
        assert!(!w.drain());
        let s = w.signaller();
        std::thread::spawn(move || {
            s.signal();
            s.signal();
        })
        .join()
        .unwrap();
        assert!(w.drain());
        assert!(!w.drain());
    }
}
