//! What the controller's integration tests share: the arena as the acting loop sees it.
//! (`allocations.rs`, a binary of its own, includes this file too.)

/// The paper's arena Env 3 as the controller sees it — its world map — with outcomes drawn
/// by a seeded generator: the other end of the acting loop, stepping the test's fake clock.
pub struct ArenaDriver {
    pub map: Box<tes_topics::WorldMap>,
    rng: rand_chacha::ChaCha8Rng,
    pub clock: tes_runtime::clock::ManualClock,
    seq: u64,
    episode: u32,
    step: u32,
    state: usize,
    flags: u32,
}

impl ArenaDriver {
    pub fn new(seed: u64) -> Self {
        use rand::SeedableRng;
        let arena = tes_perception_sim::arena::Arena::new(tes_perception_sim::arena::ArenaId::Env3);
        let map = tes_perception_sim::process::world_map(&arena).unwrap();
        let mut driver = Self {
            map,
            rng: rand_chacha::ChaCha8Rng::seed_from_u64(seed),
            // Each reading 3 µs after the last.
            clock: tes_runtime::clock::ManualClock::new(1_000_000_000).stepping(3_000),
            seq: 0,
            episode: 0,
            step: 0,
            state: 0,
            flags: 0,
        };
        driver.start_episode();
        driver
    }

    pub fn start_episode(&mut self) {
        use rand::RngExt;
        let n = self.map.out_state();
        self.state = loop {
            let s = self.rng.random_range(0..n);
            if self.map.terminal[s] == 0 {
                break s;
            }
        };
        self.step = 0;
        self.flags = tes_topics::observation_flags::EPISODE_START;
    }

    /// The observation of where the robot is now.
    pub fn observation(&mut self) -> tes_topics::Observation {
        use tes_runtime::clock::Clock;
        self.seq += 1;
        tes_topics::Observation {
            seq: self.seq,
            stamp_ns: self.clock.now_ns(),
            after_command: 0,
            episode: self.episode,
            step: self.step,
            state: self.map.attributes(self.state),
            n_features: self.map.n_features,
            features: self.map.features[self.state],
            reward: self.map.reward[self.state],
            flags: self.flags,
        }
    }

    /// The robot carries out `action`: mostly its usual effect, sometimes another.
    pub fn carry_out(&mut self, action: usize) {
        use rand::RngExt;
        let effects = self.map.n_effects as usize;
        let effect = if self.rng.random_range(0..4) == 0 {
            self.rng.random_range(0..effects)
        } else {
            (action * 7) % effects
        };
        self.state = usize::from(self.map.next_state[self.state][effect]);
        self.step += 1;
        self.flags = if self.map.terminal[self.state] != 0 {
            tes_topics::observation_flags::TERMINAL
        } else if self.step >= 40 {
            tes_topics::observation_flags::TRUNCATED
        } else {
            0
        };
    }

    /// One observation through `acting`: the command it answered with, if any (the robot
    /// carries it out; an episode's end starts the next).
    pub fn step(
        &mut self,
        acting: &mut tes_controller::acting::ActingLoop,
    ) -> Option<tes_topics::Command> {
        use tes_controller::acting::Step;
        let obs = self.observation();
        match acting.on_observation(&obs, &self.clock).unwrap() {
            Step::Act { command, .. } => {
                acting.command_sent(&self.clock).unwrap();
                self.carry_out(command.action as usize);
                Some(command)
            }
            Step::EpisodeEnded { .. } => {
                self.episode += 1;
                self.start_episode();
                None
            }
            Step::Refused(why) => panic!("refused {obs:?}: {why:?}"),
        }
    }
}
