//! The simulated brick as a transport.

use crate::brick::SimBrick;
use crate::clock::Clock;
use crate::nxt::Telegram;

use super::{Transport, TransportError};

/// The in-process simulated brick; each telegram first steps the brick to the clock's time.
#[derive(Debug)]
pub struct SimTransport<C: Clock> {
    brick: SimBrick,
    clock: C,
}

impl<C: Clock> SimTransport<C> {
    /// Wraps `brick`, driven by `clock`.
    pub fn new(brick: SimBrick, clock: C) -> Self {
        Self { brick, clock }
    }

    /// The brick, stepped to the clock's current time.
    pub fn brick(&mut self) -> &SimBrick {
        self.brick.advance_to(self.clock.now());
        &self.brick
    }

    /// The brick, for tests that poke at it.
    pub fn brick_mut(&mut self) -> &mut SimBrick {
        self.brick.advance_to(self.clock.now());
        &mut self.brick
    }

    /// The clock.
    pub fn clock(&self) -> &C {
        &self.clock
    }
}

impl<C: Clock> Transport for SimTransport<C> {
    fn transact(&mut self, telegram: &Telegram) -> Result<Option<Telegram>, TransportError> {
        self.brick.advance_to(self.clock.now());
        Ok(self.brick.handle(telegram.as_bytes()))
    }

    fn describe(&self) -> String {
        format!("sim (seed {})", self.brick.seed())
    }
}
