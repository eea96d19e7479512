//! Plan intake: the bounded ring of accepted directions, each checked and turned into step targets
//! on arrival (`gonio_shared::acceptance`); a failing one is rejected, never repaired.

use crate::capacity::PLAN_CAPACITY;
use gonio_shared::acceptance::check_direction;
use gonio_shared::kinematics::{Kinematics, Steps, Unreachable};
use gonio_shared::msg::{PlanChunk, RefuseReason};
use gonio_shared::separation::SeparationGuard;
use heapless::Deque;

/// One accepted plan direction: its index and the step positions that measure it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlannedPose {
    pub index: u32,
    pub steps: Steps,
}

/// The outcome of a chunk the queue had room for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Intake {
    /// Every direction of the chunk was accepted.
    Accepted,
    /// Directions before `index` were accepted; `index` is unreachable and the rest was dropped.
    Rejected { index: u32, reason: Unreachable },
}

pub struct PlanQueue {
    queue: Deque<PlannedPose, PLAN_CAPACITY>,
    /// Index the next chunk must start at.
    next_index: u32,
    /// `PlanEnd { total }`, once received.
    end: Option<u32>,
    /// Step positions the next accepted direction is planned from.
    tail: Steps,
}

impl Default for PlanQueue {
    fn default() -> Self {
        Self::new()
    }
}

impl PlanQueue {
    pub const fn new() -> Self {
        Self {
            queue: Deque::new(),
            next_index: 0,
            end: None,
            tail: [0; 4],
        }
    }

    /// Forget the plan; the next one starts at index 0, planned from `from`.
    pub fn reset(&mut self, from: Steps) {
        self.queue.clear();
        self.next_index = 0;
        self.end = None;
        self.tail = from;
    }

    pub fn next_index(&self) -> u32 {
        self.next_index
    }

    pub fn end(&self) -> Option<u32> {
        self.end
    }

    pub fn len(&self) -> usize {
        self.queue.len()
    }

    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// Directions the queue can take now (what a `Credit` grants); once the plan's end is known,
    /// no more than the directions still missing up to it (0 when all are in).
    pub fn free(&self) -> u16 {
        let room = PLAN_CAPACITY.saturating_sub(self.queue.len());
        let free = match self.end {
            Some(end) => room.min(usize::try_from(end.saturating_sub(self.next_index)).unwrap_or(usize::MAX)),
            None => room,
        };
        u16::try_from(free).unwrap_or(u16::MAX)
    }

    pub fn pop(&mut self) -> Option<PlannedPose> {
        self.queue.pop_front()
    }

    /// Take a chunk: refused whole (nothing changes) if it does not continue the plan or exceeds the
    /// credit, otherwise accepted up to its first unreachable direction.
    pub fn intake(
        &mut self,
        chunk: &PlanChunk,
        kin: &Kinematics<f32>,
        guard: &SeparationGuard,
    ) -> Result<Intake, RefuseReason> {
        if chunk.first_index != self.next_index {
            return Err(RefuseReason::OutOfOrder {
                expected: self.next_index,
            });
        }
        if chunk.directions.len() > usize::from(self.free()) {
            return Err(RefuseReason::NoCredit);
        }
        for d in chunk.directions.iter() {
            let index = self.next_index;
            let steps = match check_direction(kin, guard, d, &self.tail) {
                Ok(s) => s,
                Err(reason) => return Ok(Intake::Rejected { index, reason }),
            };
            let Some(after) = index.checked_add(1) else {
                return Err(RefuseReason::NoCredit);
            };
            if self.queue.push_back(PlannedPose { index, steps }).is_err() {
                // Cannot happen: the credit check above left room for the whole chunk.
                return Err(RefuseReason::NoCredit);
            }
            self.next_index = after;
            self.tail = steps;
        }
        Ok(Intake::Accepted)
    }

    /// `PlanEnd { total }`: no directions at or after `total`.
    pub fn set_end(&mut self, total: u32) -> Result<(), RefuseReason> {
        if total < self.next_index {
            return Err(RefuseReason::OutOfOrder {
                expected: self.next_index,
            });
        }
        match self.end {
            Some(end) if end != total => Err(RefuseReason::OutOfOrder { expected: end }),
            _ => {
                self.end = Some(total);
                Ok(())
            }
        }
    }
}
