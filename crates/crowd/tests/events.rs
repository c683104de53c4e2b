//! Scheduled events: a group released at a time stands still until then (unless pushed) and
//! walks after; an inflow source brings exactly the people it owes, each where there is room,
//! in order of id, waiting when its area is full; sources draw from streams of their own.

use moreau_crowd::{EntryRecord, Observer, ObserverError, Scene, Simulation};

/// A corridor `length` m × 4 m, exit (remove) at its right end; `rest` is TOML for the groups
/// and sources, each destined for "end".
fn corridor(length: f64, horizon: f64, rest: &str) -> Scene {
    let text = format!(
        r#"
name = "corridor"
seed = 11
[area]
outer = [[0.0, 0.0], [{length}, 0.0], [{length}, 4.0], [0.0, 4.0]]
[[exits]]
name = "end"
area = [[{x}, 0.0], [{length}, 0.0], [{length}, 4.0], [{x}, 4.0]]
action = "remove"
{rest}
[time]
horizon = {horizon}
step = 0.05
output_interval = 0.5
[solver]
eps_kappa = 1e-3
max_violation = 1e-6
grid_cell = 0.1
"#,
        x = length - 0.5
    );
    Scene::from_toml(&text, "corridor").unwrap()
}

/// Who entered, in order.
#[derive(Default)]
struct Entries(Vec<EntryRecord>);

impl Observer for Entries {
    fn enter(&mut self, record: &EntryRecord) -> Result<(), ObserverError> {
        self.0.push(*record);
        Ok(())
    }
}

/// Steps `sim` to `t_end` one step at a time, checking after each that nobody overlaps beyond
/// the certified violation and that ids increase; `each` sees the simulation and who entered
/// so far after every step.
fn run_checked(
    sim: &mut Simulation,
    t_end: f64,
    entries: &mut Entries,
    mut each: impl FnMut(&Simulation, &[EntryRecord]),
) -> usize {
    let bound = sim.scene().solver.max_violation;
    let mut steps = 0;
    while sim.advance_step(t_end, entries).unwrap().is_some() {
        steps += 1;
        let gap = sim.min_gap(1.0);
        assert!(
            gap >= -bound,
            "t = {}: gap {gap} below −{bound}",
            sim.time()
        );
        let ids = sim.people().ids();
        assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids do not increase");
        assert!(ids.iter().all(|&id| (id as usize) < sim.total_people()));
        each(sim, &entries.0);
    }
    steps
}

#[test]
fn a_group_released_at_2_s_stands_until_then_and_walks_after() {
    // Alone in the corridor: nobody pushes them. A group released at 5 s (where the sum of
    // 100 steps of 0.05 s is 4.99999999999999 s) and one released at once (release is per
    // group), far from each other.
    let scene = corridor(
        40.0,
        6.0,
        r#"
[[groups]]
name = "at 2 s"
positions = [[3.0, 2.0]]
radius = 0.2
speed = 1.0
destination = "end"
release = 2.0
[[groups]]
name = "at 5 s"
positions = [[12.0, 3.0]]
radius = 0.2
speed = 1.0
destination = "end"
release = 5.0
[[groups]]
name = "now"
positions = [[22.0, 1.0]]
radius = 0.2
speed = 1.0
destination = "end"
"#,
    );
    let mut sim = Simulation::new(scene).unwrap();
    let index = |g: u32| sim.people().groups().iter().position(|&x| x == g).unwrap();
    let people = [(index(0), 2.0), (index(1), 5.0), (index(2), 0.0)];
    let start = sim.people().positions().to_vec();
    let bits = |q: &[f64], i: usize| [q[2 * i].to_bits(), q[2 * i + 1].to_bits()];
    let mut standing = [0; 3];
    let mut velocities = vec![0.0; 6];
    loop {
        let t = sim.time();
        sim.desired_velocities(&mut velocities);
        let before = sim.people().positions().to_vec();
        if sim.advance_step(6.0, &mut ()).unwrap().is_none() {
            break;
        }
        let after = sim.people().positions();
        for (k, &(i, release)) in people.iter().enumerate() {
            // Released at the step that starts at the release time (times are sums of
            // steps: within rounding).
            if t < release - 1e-6 {
                assert_eq!(velocities[2 * i..2 * i + 2], [0.0, 0.0], "t = {t}");
                assert_eq!(
                    bits(after, i),
                    bits(&start, i),
                    "t = {t}: moved before its release at {release}"
                );
                standing[k] += 1;
            } else {
                assert!(velocities[2 * i] > 0.9, "t = {t}: {velocities:?}");
                assert!(
                    after[2 * i] > before[2 * i] + 0.04,
                    "t = {t}: did not walk after its release at {release}"
                );
            }
        }
    }
    // Steps of 0.05 s: 40 start before 2 s, 100 before 5 s; 120 in all.
    assert_eq!(sim.steps(), 120);
    assert_eq!(standing, [40, 100, 0]);
}

#[test]
fn a_group_not_yet_released_can_be_pushed() {
    // A walker right behind a standing person pushes them along the corridor.
    let scene = corridor(
        20.0,
        1.0,
        r#"
[[groups]]
name = "standing"
positions = [[5.0, 2.0]]
radius = 0.25
speed = 1.0
destination = "end"
release = 10.0
[[groups]]
name = "walker"
positions = [[4.45, 2.0]]
radius = 0.25
speed = 1.2
destination = "end"
"#,
    );
    let mut sim = Simulation::new(scene).unwrap();
    let standing = sim.people().groups().iter().position(|&g| g == 0).unwrap();
    let x0 = sim.people().position(standing)[0];
    sim.advance_to(1.0, &mut ()).unwrap();
    let x1 = sim.people().position(standing)[0];
    assert!(x1 > x0 + 0.2, "pushed from {x0} to {x1} only");
}

#[test]
fn a_source_at_2_per_second_brings_20_people_in_10_s_each_when_due() {
    // An empty 40 m corridor: always room at the gate, and nobody reaches the exit in 10 s.
    let scene = corridor(
        40.0,
        10.0,
        r#"
[[sources]]
name = "gate"
area = [[0.0, 0.0], [2.0, 0.0], [2.0, 4.0], [0.0, 4.0]]
rate = 2.0
radius = { min = 0.18, max = 0.25 }
speed = 1.3
destination = "end"
"#,
    );
    let mut sim = Simulation::new(scene).unwrap();
    assert_eq!(sim.total_people(), 0);
    let mut entries = Entries::default();
    let steps = run_checked(&mut sim, 10.0, &mut entries, |_, _| {});
    assert_eq!(steps, 200);
    assert_eq!(sim.total_people(), 20);
    assert_eq!(sim.people().len(), 20);
    assert_eq!(sim.people().ids(), (0..20).collect::<Vec<u32>>());
    assert!(sim.exit_records().is_empty());
    // Person k (from 0) is due at (k + 1) / 2 s and enters after the first step ending then.
    for (k, e) in entries.0.iter().enumerate() {
        let due = (k + 1) as f64 / 2.0;
        assert_eq!(e.id, k as u32);
        assert!(
            e.t >= due - 1e-9 && e.t < due + 0.05 - 1e-9,
            "person {k} due at {due} entered at {}",
            e.t
        );
        let i = sim.people().index_of(e.id).unwrap();
        assert_eq!(sim.people().radii()[i], e.radius);
        assert!((0.18..=0.25).contains(&e.radius));
    }
}

#[test]
fn a_source_whose_area_holds_one_person_makes_the_others_wait_and_owes_them_all() {
    // A 0.2 m square: two centres in it are closer than two radii (0.4 m), so it holds one
    // person at a time; the next enters once the last has walked on. 10 a second for 2 s.
    let scene = corridor(
        30.0,
        20.0,
        r#"
[[sources]]
name = "turnstile"
area = [[0.5, 1.9], [0.7, 1.9], [0.7, 2.1], [0.5, 2.1]]
rate = 10.0
stop = 2.0
radius = 0.2
speed = 1.3
destination = "end"
"#,
    );
    let mut sim = Simulation::new(scene).unwrap();
    let mut entries = Entries::default();
    let (mut most_inside, mut waited) = (0, false);
    run_checked(&mut sim, 20.0, &mut entries, |sim, _| {
        let people = sim.people();
        let inside = (0..people.len())
            .filter(|&i| {
                let p = people.position(i);
                (0.5..=0.7).contains(&p[0]) && (1.9..=2.1).contains(&p[1])
            })
            .count();
        most_inside = most_inside.max(inside);
        let owed = ((10.0 * sim.time() + 1e-9).floor() as usize).min(20);
        waited |= sim.total_people() + 5 <= owed;
    });
    assert_eq!(most_inside, 1);
    assert!(waited, "the queue never held 5 people");
    // Everyone owed entered, in order, and nobody more (the source stopped at 2 s).
    assert_eq!(sim.total_people(), 20);
    assert_eq!(
        entries.0.iter().map(|e| e.id).collect::<Vec<_>>(),
        (0..20).collect::<Vec<u32>>()
    );
    assert!(entries.0.windows(2).all(|w| w[0].t < w[1].t));
    assert!(
        entries.0[19].t > 4.0,
        "the last entered at {}",
        entries.0[19].t
    );
}

#[test]
fn a_count_caps_a_source_and_a_source_starts_at_its_start() {
    let scene = corridor(
        40.0,
        6.0,
        r#"
[[sources]]
name = "gate"
area = [[0.0, 0.0], [2.0, 0.0], [2.0, 4.0], [0.0, 4.0]]
rate = 4.0
start = 2.5
count = 7
radius = 0.2
speed = 1.3
destination = "end"
"#,
    );
    let mut sim = Simulation::new(scene).unwrap();
    let mut entries = Entries::default();
    run_checked(&mut sim, 6.0, &mut entries, |_, _| {});
    assert_eq!(sim.total_people(), 7);
    assert!(
        entries.0[0].t >= 2.75 - 1e-9 && entries.0[0].t < 2.8,
        "{}",
        entries.0[0].t
    );
}

#[test]
fn a_source_draws_from_its_own_stream_whatever_other_sources_do() {
    let gate = r#"
[[sources]]
name = "gate"
area = [[0.0, 0.0], [2.0, 0.0], [2.0, 4.0], [0.0, 4.0]]
rate = 1.0
radius = { min = 0.18, max = 0.25 }
speed = { min = 1.0, max = 1.4 }
destination = "end"
"#;
    let other = r#"
[[sources]]
name = "middle"
area = [[20.0, 0.0], [22.0, 0.0], [22.0, 4.0], [20.0, 4.0]]
rate = 3.0
radius = 0.3
speed = 0.5
destination = "end"
"#;
    // The gate's people as they enter: time, radius, desired speed, position (bits).
    let entered = |rest: &str| {
        let mut sim = Simulation::new(corridor(40.0, 3.0, rest)).unwrap();
        let mut entries = Entries::default();
        let mut gate = Vec::new();
        while sim.advance_step(3.0, &mut entries).unwrap().is_some() {
            for e in entries.0.drain(..).filter(|e| e.source == 0) {
                let i = sim.people().index_of(e.id).unwrap();
                let p = sim.people().position(i);
                let speed = sim.people().speeds()[i];
                gate.push((e.t, e.radius, speed, [p[0].to_bits(), p[1].to_bits()]));
            }
        }
        (gate, sim.total_people())
    };
    let (alone, n_alone) = entered(gate);
    let (beside, n_beside) = entered(&format!("{gate}{other}"));
    assert_eq!((n_alone, n_beside), (3, 3 + 9));
    assert_eq!(alone, beside);
}

#[test]
fn newcomers_keep_clear_of_moving_bodies() {
    // A 1 m box drifting through the gate's area while people enter there, 4 a second.
    let scene = corridor(
        30.0,
        6.0,
        r#"
[[sources]]
name = "gate"
area = [[0.0, 0.0], [3.0, 0.0], [3.0, 4.0], [0.0, 4.0]]
rate = 4.0
radius = 0.2
speed = 0.8
destination = "end"
[[moving]]
name = "box"
polygon = [[0.5, 1.5], [1.5, 1.5], [1.5, 2.5], [0.5, 2.5]]
keyframes = [{ t = 0.0 }, { t = 6.0, offset = [1.2, 0.0] }]
"#,
    );
    let mut sim = Simulation::new(scene).unwrap();
    let mut entries = Entries::default();
    let mut segments = Vec::new();
    let mut near_the_box = 0;
    run_checked(&mut sim, 6.0, &mut entries, |sim, entered| {
        let t = sim.time();
        sim.moving().segments_at(t, &mut segments);
        for e in entered.iter().filter(|e| e.t == t) {
            let p = sim.people().position(sim.people().index_of(e.id).unwrap());
            assert!(!sim.moving().inside(t, p), "t = {t}: {p:?} in the box");
            let gap = segments
                .iter()
                .map(|s| s.distance(p) - e.radius)
                .fold(f64::INFINITY, f64::min);
            assert!(gap >= 0.0, "t = {t}: {p:?} overlaps the box by {}", -gap);
            near_the_box += usize::from(gap < 0.5);
        }
    });
    assert_eq!(sim.total_people(), 24);
    assert!(
        near_the_box > 0,
        "nobody entered near the box: the test would not see it"
    );
}

#[test]
fn a_step_far_longer_than_the_horizon_did_not_hang_the_inflow_count() {
    // Found by the fuzzer: with time.step = 2e301 (adaptive steps, which never take it) the
    // tolerance on due times was 1e-9 × step = 2e292 s, and counting the people due never
    // ended.
    let scene = moreau_crowd::Scene::from_toml(
        r#"
name = "long-step"
seed = 3
[area]
outer = [[0.0, 0.0], [12.0, 0.0], [12.0, 6.0], [0.0, 6.0]]
[[exits]]
name = "east"
segment = [[12.0, 2.0], [12.0, 4.0]]
action = "remove"
[[sources]]
name = "gate"
area = [[0.2, 0.2], [1.0, 0.2], [1.0, 1.0], [0.2, 1.0]]
rate = 1.0
radius = 0.2
speed = 1.0
destination = "east"
[time]
horizon = 10.0
output_interval = 0.5
step = 2e301
tol = 5.0
"#,
        "<test>",
    )
    .unwrap();
    let mut sim = moreau_crowd::Simulation::new(scene).unwrap();
    sim.advance_to(10.0, &mut ()).unwrap();
    // One person due every second from t = 1 s: ten by the horizon.
    assert_eq!(sim.total_people(), 10);
}

#[test]
fn a_blocked_sources_people_left_waiting_were_counted_nowhere() {
    // The turnstile above, stopped at its 2 s: people due by then who found no room were in no
    // frame and no count (50 due, 23 entered was reported as a run of 23 people). The tally
    // says, after every step, how many were due (10 a second, counted here) and how many came.
    let scene = corridor(
        30.0,
        2.0,
        r#"
[[sources]]
name = "turnstile"
area = [[0.5, 1.9], [0.7, 1.9], [0.7, 2.1], [0.5, 2.1]]
rate = 10.0
radius = 0.2
speed = 1.3
destination = "end"
"#,
    );
    let mut sim = Simulation::new(scene).unwrap();
    let at_start = sim.source_tallies();
    assert_eq!(at_start.len(), 1);
    assert_eq!((at_start[0].due, at_start[0].entered), (0, 0));
    let mut entries = Entries::default();
    run_checked(&mut sim, 2.0, &mut entries, |sim, entered| {
        let tally = &sim.source_tallies()[0];
        let owed = (10.0 * sim.time() + 1e-9).floor() as u64;
        assert_eq!(tally.name, "turnstile");
        assert_eq!(tally.due, owed, "t = {}", sim.time());
        assert_eq!(tally.entered as usize, entered.len());
        assert_eq!(tally.waiting(), owed - entered.len() as u64);
    });
    let tally = &sim.source_tallies()[0];
    assert_eq!(tally.due, 20);
    assert!(
        tally.waiting() >= 10,
        "a square that holds one person let {} of 20 in within 2 s",
        tally.entered
    );
}
