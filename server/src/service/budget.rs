//! The server's memory budget: one account of the bytes that loaded assets, frames in flight
//! and their encode buffers take, so that load beyond the machine's memory waits or is refused
//! (503 with `Retry-After`) instead of ending in an out-of-memory kill.
//!
//! Every holder keeps a [`Charge`]; dropping it gives the bytes back and wakes the waiters at
//! once (a deleted asset's charge drops with its textures, a frame's when its response is built).

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use tokio::sync::Notify;

use super::assets::describe_bytes;
use super::error::AppError;

/// Bytes one rendered pixel is charged while its request is served: the frame in host memory
/// (RGBA8 colour and f32 depth, 8 bytes), its encoded colour and depth (at most 8 bytes: PNG,
/// JPEG and WebP of RGBA8 stay under 4 bytes a pixel plus headers, depth as `.npy`/EXR f32 is 4,
/// PNG16 is 2), and the renderer's output targets (colour, depth, their readback copy and the
/// guide passes' depth: under 16 bytes a pixel, held once per render worker).
pub const FRAME_BYTES_PER_PIXEL: u64 = 32;

/// Fixed bytes charged per frame on top of its pixels (headers, small buffers, bookkeeping).
pub const FRAME_OVERHEAD_BYTES: u64 = 64 << 10;

/// Bytes charged for serving one `width × height` frame.
pub fn frame_bytes(width: u32, height: u32) -> u64 {
    (u64::from(width) * u64::from(height))
        .saturating_mul(FRAME_BYTES_PER_PIXEL)
        .saturating_add(FRAME_OVERHEAD_BYTES)
}

/// The whole server's memory budget.
pub struct MemoryBudget {
    total: u64,
    used: Mutex<u64>,
    freed: Notify,
}

/// Bytes taken from a [`MemoryBudget`], given back on drop.
pub struct Charge {
    bytes: u64,
    budget: Arc<MemoryBudget>,
}

impl Drop for Charge {
    fn drop(&mut self) {
        if self.bytes == 0 {
            return;
        }
        {
            let mut used = self
                .budget
                .used
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            *used = used.saturating_sub(self.bytes);
        }
        self.budget.freed.notify_waiters();
    }
}

impl std::fmt::Debug for Charge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Charge")
            .field("bytes", &self.bytes)
            .finish_non_exhaustive()
    }
}

impl MemoryBudget {
    /// A budget of `total` bytes, nothing charged.
    pub fn new(total: u64) -> Arc<Self> {
        Arc::new(Self {
            total,
            used: Mutex::new(0),
            freed: Notify::new(),
        })
    }

    /// The budget in bytes.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// Bytes charged now.
    pub fn used(&self) -> u64 {
        *self.used.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Charges `bytes` if they fit now; otherwise returns the bytes charged now.
    ///
    /// # Errors
    /// The bytes already charged, when `bytes` do not fit beside them.
    pub fn try_charge(self: &Arc<Self>, bytes: u64) -> Result<Charge, u64> {
        let mut used = self.used.lock().unwrap_or_else(PoisonError::into_inner);
        if used.saturating_add(bytes) > self.total {
            return Err(*used);
        }
        *used += bytes;
        Ok(Charge {
            bytes,
            budget: Arc::clone(self),
        })
    }

    /// Charges `bytes` for `what`, waiting up to `wait` for other charges to be given back.
    ///
    /// # Errors
    /// [`AppError::OverLimit`] (413) when `bytes` exceed the whole budget (no wait can help);
    /// [`AppError::Unavailable`] (503, with `Retry-After`) when they do not fit within `wait`.
    pub async fn charge(
        self: &Arc<Self>,
        bytes: u64,
        wait: Duration,
        what: &str,
    ) -> Result<Charge, AppError> {
        if bytes > self.total {
            return Err(AppError::OverLimit(format!(
                "{what} needs {}, more than the server's memory budget of {} (--memory-budget)",
                describe_bytes(bytes),
                describe_bytes(self.total),
            )));
        }
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            // Registered before the attempt, so a charge given back in between is not missed.
            let freed = self.freed.notified();
            tokio::pin!(freed);
            freed.as_mut().enable();
            match self.try_charge(bytes) {
                Ok(charge) => return Ok(charge),
                Err(used) => {
                    if tokio::time::timeout_at(deadline, freed).await.is_err() {
                        return Err(AppError::Unavailable(format!(
                            "the server's memory budget is taken ({} of {} in use; {what} \
                             needs {}): retry shortly",
                            describe_bytes(used),
                            describe_bytes(self.total),
                            describe_bytes(bytes),
                        )));
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charges_add_up_and_are_given_back_on_drop() {
        let budget = MemoryBudget::new(100);
        let a = budget.try_charge(60).expect("fits");
        assert_eq!(budget.used(), 60);
        assert_eq!(budget.try_charge(41).expect_err("over"), 60);
        let b = budget.try_charge(40).expect("fits exactly");
        assert_eq!(budget.used(), 100);
        drop(a);
        assert_eq!(budget.used(), 40);
        drop(b);
        assert_eq!(budget.used(), 0);
    }

    #[test]
    fn frame_bytes_grow_with_pixels() {
        assert_eq!(frame_bytes(0, 0), FRAME_OVERHEAD_BYTES);
        assert_eq!(
            frame_bytes(512, 512),
            512 * 512 * FRAME_BYTES_PER_PIXEL + FRAME_OVERHEAD_BYTES
        );
        // The largest frame (u32 sides) saturates instead of overflowing.
        assert_eq!(frame_bytes(u32::MAX, u32::MAX), u64::MAX);
    }

    #[tokio::test]
    async fn a_waiter_gets_memory_given_back_within_its_wait() {
        let budget = MemoryBudget::new(100);
        let held = budget.try_charge(80).expect("fits");
        let waiter = {
            let budget = Arc::clone(&budget);
            tokio::spawn(async move { budget.charge(50, Duration::from_secs(10), "a frame").await })
        };
        tokio::time::sleep(Duration::from_millis(50)).await;
        assert!(
            !waiter.is_finished(),
            "the waiter must wait while memory is taken"
        );
        drop(held);
        let charge = waiter.await.expect("task").expect("charged once freed");
        assert_eq!(budget.used(), 50);
        drop(charge);
        assert_eq!(budget.used(), 0);
    }

    #[tokio::test]
    async fn refusals_say_503_when_busy_and_413_when_never_possible() {
        let budget = MemoryBudget::new(100);
        let _held = budget.try_charge(80).expect("fits");
        let busy = budget
            .charge(50, Duration::from_millis(20), "a frame")
            .await
            .expect_err("busy");
        assert!(matches!(busy, AppError::Unavailable(_)), "{busy}");
        assert!(busy.to_string().contains("80 bytes of 100 bytes"), "{busy}");
        let never = budget
            .charge(101, Duration::from_secs(10), "a frame")
            .await
            .expect_err("too large");
        assert!(matches!(never, AppError::OverLimit(_)), "{never}");
        assert_eq!(budget.used(), 80, "refusals charge nothing");
    }
}
