//! Proof that the learning hot path allocates nothing after construction.
//!
//! A counting global allocator counts, per thread, every allocation made while a
//! [`Tracked`] guard is alive; tests run in parallel on their own threads, so each counts
//! only its own work.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use tes_learning::mdagl::synthetic::{SparseMultinomialStream, SyntheticSpec};
use tes_learning::mdagl::{Features, Mdagl, MdaglParams};

// The shared driver of the integration tests (`it/`), included here: this binary installs
// its own global allocator, so it cannot be one of their modules.
#[path = "it/driver.rs"]
mod driver;
use driver::ArenaDriver;

struct CountingAllocator;

thread_local! {
    static TRACKING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn note_allocation() {
    // `try_with`: thread-locals may already be gone while a thread shuts down.
    let _ = TRACKING.try_with(|t| {
        if t.get() {
            let _ = ALLOCATIONS.try_with(|a| a.set(a.get() + 1));
        }
    });
}

// SAFETY: defers every operation to the system allocator; counting has no effect on memory.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_allocation();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_allocation();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_allocation();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

/// Counts this thread's allocations while alive.
struct Tracked;

impl Tracked {
    fn start() -> Self {
        ALLOCATIONS.with(|a| a.set(0));
        TRACKING.with(|t| t.set(true));
        Tracked
    }
    fn allocations(&self) -> u64 {
        ALLOCATIONS.with(Cell::get)
    }
}

impl Drop for Tracked {
    fn drop(&mut self) {
        TRACKING.with(|t| t.set(false));
    }
}

#[test]
fn the_counter_sees_allocations() {
    let guard = Tracked::start();
    let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(8));
    assert!(guard.allocations() >= 1);
    drop(v);
}

#[test]
fn mdagl_predict_and_update_allocate_nothing() {
    // Sparse binary input: the paper's robot shape, d = 312, K = 20.
    let spec = SyntheticSpec {
        classes: 20,
        features: 312,
        relevant: 12,
        density: 15.0 / 312.0,
        ..SyntheticSpec::default()
    };
    let mut data = SparseMultinomialStream::new(spec, 5).unwrap();
    let rows: Vec<(usize, Vec<u32>)> = (0..2_000)
        .map(|_| {
            let (y, x) = data.next_row();
            (y, x.to_vec())
        })
        .collect();
    let mut model = Mdagl::new(20, 312, MdaglParams::default()).unwrap();
    let mut probs = vec![0.0; 20];
    let mut checksum = 0.0;

    let guard = Tracked::start();
    for _ in 0..5 {
        for (y, x) in &rows {
            let x = Features::SparseBinary(x);
            model.predict_into(x, &mut probs).unwrap();
            checksum += model.predict(x).unwrap()[*y];
            checksum += model.log_prob(x, *y).unwrap();
            checksum += model.update(x, *y).unwrap().log_prob;
            // Refused input takes the same no-allocation path.
            assert!(model.update(x, 20).is_err());
        }
    }
    let allocations = guard.allocations();
    drop(guard);
    assert_eq!(allocations, 0, "the hot path allocated");
    assert!(checksum.is_finite());
    assert_eq!(model.n_updates(), 10_000);
}

#[test]
fn mdagl_dense_updates_allocate_nothing() {
    let mut model = Mdagl::new(
        5,
        210,
        MdaglParams {
            intercept: true,
            ..MdaglParams::default()
        },
    )
    .unwrap();
    let x: Vec<f64> = (0..210).map(|i| ((i * 37) % 11) as f64 / 10.0).collect();
    let guard = Tracked::start();
    for t in 0..5_000 {
        model.update(Features::Dense(&x), t % 5).unwrap();
    }
    assert_eq!(guard.allocations(), 0);
}

/// A 10×10 open grid, 4 moves, 5 effects (4 moves + stay), 60 features: bias, a "mud"
/// marker on a third of the cells, and random irrelevant ones.
fn mud_grid() -> std::sync::Arc<tes_learning::cmdp::CmdpStructure> {
    let (w, n) = (10usize, 100usize);
    let features: Vec<Vec<u32>> = (0..n)
        .map(|s| {
            let mut f = vec![0u32];
            if s.is_multiple_of(3) {
                f.push(1);
            }
            f.extend((2..60u32).filter(|i| (s as u32 * 7 + i * 13).is_multiple_of(5)));
            f
        })
        .collect();
    let mut reward = vec![-0.01; n];
    reward[n - 1] = 1.0;
    let mut terminal = vec![false; n];
    terminal[n - 1] = true;
    let step = |s: usize, e: usize| -> usize {
        let (x, y) = (s % w, s / w);
        match e {
            0 if y + 1 < w => s + w,
            1 if x + 1 < w => s + 1,
            2 if y > 0 => s - w,
            3 if x > 0 => s - 1,
            _ => s,
        }
    };
    std::sync::Arc::new(
        tes_learning::cmdp::CmdpStructure::new(n, 4, 5, 60, step, reward, terminal, |s| {
            &features[s]
        })
        .unwrap(),
    )
}

/// Runs `steps` act/observe steps of `agent` on the mud grid from `*s`: mud cells stall one
/// move in three.
fn run_on_mud_grid(
    agent: &mut dyn tes_learning::agents::Agent,
    structure: &tes_learning::cmdp::CmdpStructure,
    s: &mut usize,
    steps: usize,
) {
    for t in 0..steps {
        let a = agent.act(*s).unwrap();
        let e = if structure.features(*s).contains(&1) && t.is_multiple_of(3) {
            4
        } else {
            a
        };
        agent.observe(*s, a, e).unwrap();
        *s = structure.next_state(*s, e);
        if structure.is_terminal(*s) {
            *s = t % (structure.n_states() - 1);
        }
    }
}

/// loreRL's whole step — choose an action (re-planning on the learned model), learn from its
/// effect, refresh the model — allocates nothing after construction.
#[test]
fn lore_rl_steps_allocate_nothing() {
    use tes_learning::agents::{LoreRl, LoreRlParams};

    let structure = mud_grid();
    let mut agent = LoreRl::new(structure.clone(), LoreRlParams::default(), 9).unwrap();
    let mut s = 0;
    run_on_mud_grid(&mut agent, &structure, &mut s, 200); // warm-up
    let guard = Tracked::start();
    run_on_mud_grid(&mut agent, &structure, &mut s, 2_000);
    assert_eq!(guard.allocations(), 0, "the acting loop allocated");
}

/// A 9-view library for the mud grid: three tasks whose fresh views won (4 + 4 + 1 views).
fn nine_view_library() -> tes_learning::library::ViewLibrary {
    use tes_learning::library::{ActionOutcome, LibraryParams, ViewLibrary, Winner};

    let mut library = ViewLibrary::new(4, 5, 60, LibraryParams::default()).unwrap();
    for (task, actions) in [(0usize, 4usize), (1, 4), (2, 1)] {
        let outcomes = (0..actions)
            .map(|action| {
                let mut model = library.fresh_model();
                for i in 0..50u32 {
                    let x = [0, 2 + (i + task as u32) % 58];
                    model
                        .update(Features::SparseBinary(&x), (action + task) % 5)
                        .unwrap();
                }
                ActionOutcome {
                    action,
                    observations: 50,
                    winner: Winner::Fresh,
                    model,
                    score: -10.0,
                    library_scores: vec![],
                }
            })
            .collect();
        library.end_task(outcomes).unwrap();
    }
    assert_eq!(library.len(), 9);
    library
}

/// TES's whole step with a 9-view library — act, score every view of the action (working
/// copies and frozen originals), update the working views, re-select, refresh, re-plan —
/// allocates nothing after construction.
#[test]
fn tes_steps_with_a_nine_view_library_allocate_nothing() {
    use tes_learning::agents::{Tes, TesParams};

    let structure = mud_grid();
    let mut agent = Tes::new(
        structure.clone(),
        nine_view_library(),
        TesParams::default(),
        4,
    )
    .unwrap();
    let mut s = 0;
    run_on_mud_grid(&mut agent, &structure, &mut s, 200); // warm-up
    let guard = Tracked::start();
    run_on_mud_grid(&mut agent, &structure, &mut s, 10_000);
    assert_eq!(guard.allocations(), 0, "the TES step allocated");
    assert_eq!(
        agent.working_views(0).len(),
        4,
        "3 library views + the fresh one"
    );
}

/// The controller's acting loop itself — refuse or accept the observation, adopt a finished
/// plan, act, then derive the effect, score and update every view of the action, hand the
/// planner a new snapshot, report ended episodes, send keep-alives — with planning on its own
/// thread or between its polls in slices, deciding first or learning first, from a library
/// learned on the same map: allocates nothing over 10 000 observations after the warm-up.
#[test]
fn the_real_time_acting_loop_allocates_nothing() {
    use tes_controller::acting::{ActingLoop, ActingSettings, Order};
    use tes_controller::realtime::{Planner, PlannerThread, SlicedPlanner};
    use tes_learning::library::{LibraryParams, ViewLibrary};
    use tes_learning::plan::PlannerParams;

    let params = PlannerParams::default();
    let settings = ActingSettings {
        keepalive: Some(std::time::Duration::from_millis(250)),
        save_interval: std::time::Duration::ZERO,
        ..ActingSettings::default()
    };
    let thread = |s| Ok(Planner::Thread(PlannerThread::spawn(s, params)?));
    let sliced = |s| {
        Ok(Planner::BetweenPolls(Box::new(SlicedPlanner::new(
            s, params, 32,
        )?)))
    };
    // A first task grows the library the counted runs start from.
    let mut driver = ArenaDriver::new(3);
    let (actions, effects, features) = (
        driver.map.n_actions as usize,
        driver.map.n_effects as usize,
        driver.map.n_features as usize,
    );
    let empty = ViewLibrary::new(actions, effects, features, LibraryParams::default()).unwrap();
    let mut first = ActingLoop::new(driver.map.clone(), empty, settings, sliced).unwrap();
    drive(&mut driver, &mut first, 3_000);
    let (library, _) = first.finish().1.finish_task().unwrap();
    assert!(!library.is_empty(), "the first task left no view");

    for (who, planner, order) in [
        (
            "planning on a thread",
            &thread as &dyn Fn(_) -> _,
            Order::DecideFirst,
        ),
        ("planning between polls", &sliced, Order::DecideFirst),
        (
            "planning on a thread, learning first",
            &thread,
            Order::LearnFirst,
        ),
    ] {
        let mut driver = ArenaDriver::new(11);
        let settings = ActingSettings { order, ..settings };
        let mut acting =
            ActingLoop::new(driver.map.clone(), library.clone(), settings, planner).unwrap();
        drive(&mut driver, &mut acting, 500); // warm-up
        let guard = Tracked::start();
        let commands = drive(&mut driver, &mut acting, 10_000);
        let allocations = guard.allocations();
        drop(guard);
        assert_eq!(allocations, 0, "the acting loop allocated, {who}");
        let counts = acting.counts();
        assert!(
            commands > 8_000 && counts.episodes > 100,
            "{who}: {counts:?}"
        );
        assert!(counts.keepalives > 0, "{who}: {counts:?}");
        // How many during the run depends on scheduling (a planner thread yields to
        // everything); that plans flow at all is the point: given time, one comes.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while acting.plans() <= 1 && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(5));
            drive(&mut driver, &mut acting, 1);
        }
        assert!(acting.plans() > 1, "{who}: no plan was adopted");
    }
}

/// `steps` observations through `acting`, with `t % 40` polls of planning between them and an
/// idle wait (a keep-alive) every 50; returns the commands published.
fn drive(
    driver: &mut ArenaDriver,
    acting: &mut tes_controller::acting::ActingLoop,
    steps: usize,
) -> u64 {
    let mut commands = 0;
    for t in 0..steps {
        if let Some(command) = driver.step(acting) {
            std::hint::black_box(command);
            commands += 1;
        }
        for _ in 0..t % 40 {
            acting.plan_between_polls();
        }
        if t % 50 == 49 {
            driver.clock.advance(300_000_000);
            std::hint::black_box(acting.on_idle(&driver.clock));
        }
    }
    commands
}
