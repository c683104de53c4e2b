//! Placing a scene's people: fixed positions or random draws without overlap, checked against
//! walls and each other, then numbered along a space-filling curve.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::CrowdError;
use crate::exits::Exits;
use crate::geometry::Polygon;
use crate::moving::MovingBodies;
use crate::people::{People, Place};
use crate::scene::{Quantity, Scene};
use crate::walls::Walls;

/// A value of `q`: itself, or drawn uniformly from `rng`.
pub(crate) fn draw(q: &Quantity, rng: &mut ChaCha8Rng) -> f64 {
    match *q {
        Quantity::Fixed(x) => x,
        Quantity::Uniform { min, max } => {
            if max > min {
                rng.random_range(min..=max)
            } else {
                min
            }
        }
    }
}

/// Overlap test against people already placed, through a grid of cells of side at least
/// `2 r_max` over the box where they can be placed, each cell the list of its people (a head
/// per cell, a next per person). It was a hash map of cells: 63 % of building a million
/// people's scene (~8 s), hashing and probing nine cells a try.
struct Placed {
    cell: f64,
    lo: [f64; 2],
    nx: usize,
    ny: usize,
    /// Per cell, the last person put there (`NONE` if none).
    head: Vec<u32>,
    /// Per person, the person put in the same cell before them.
    next: Vec<u32>,
    pos: Vec<[f64; 2]>,
    radius: Vec<f64>,
}

const NONE: u32 = u32::MAX;

impl Placed {
    /// A grid for `people` people of radius at most `r_max` placed in the box `[lo, hi]`: its
    /// cells have side `2 r_max` or more, at most about `4 people + 16` of them.
    fn new(lo: [f64; 2], hi: [f64; 2], r_max: f64, people: usize) -> Self {
        let span = [(hi[0] - lo[0]).max(0.0), (hi[1] - lo[1]).max(0.0)];
        let cell = crate::broad::cell_within_budget(
            (2.0 * r_max).max(1e-9),
            span,
            (4 * people + 16) as f64,
        );
        let nx = (span[0] / cell) as usize + 1;
        let ny = (span[1] / cell) as usize + 1;
        Self {
            cell,
            lo,
            nx,
            ny,
            head: vec![NONE; nx * ny],
            next: Vec::with_capacity(people),
            pos: Vec::with_capacity(people),
            radius: Vec::with_capacity(people),
        }
    }
    /// The cell of `p` (which lies in the box, up to rounding).
    fn key(&self, p: [f64; 2]) -> (usize, usize) {
        let at = |x: f64, lo: f64, n: usize| (((x - lo) / self.cell).max(0.0) as usize).min(n - 1);
        (at(p[0], self.lo[0], self.nx), at(p[1], self.lo[1], self.ny))
    }
    fn overlaps(&self, p: [f64; 2], r: f64) -> Option<usize> {
        let (cx, cy) = self.key(p);
        for y in cy.saturating_sub(1)..=(cy + 1).min(self.ny - 1) {
            for x in cx.saturating_sub(1)..=(cx + 1).min(self.nx - 1) {
                let mut j = self.head[y * self.nx + x];
                while j != NONE {
                    let q = self.pos[j as usize];
                    if ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()
                        < r + self.radius[j as usize]
                    {
                        return Some(j as usize);
                    }
                    j = self.next[j as usize];
                }
            }
        }
        None
    }
    fn insert(&mut self, p: [f64; 2], r: f64) {
        let (cx, cy) = self.key(p);
        let c = cy * self.nx + cx;
        self.next.push(self.head[c]);
        self.head[c] = self.pos.len() as u32;
        self.pos.push(p);
        self.radius.push(r);
    }
}

/// The box where `scene`'s groups can place people (their listed positions and spawn regions)
/// and how many people they place.
fn placement_box(scene: &Scene) -> ([f64; 2], [f64; 2], usize) {
    let (mut lo, mut hi, mut people) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2], 0);
    let mut cover = |p: &[f64; 2]| {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    };
    for group in &scene.groups {
        match (&group.positions, group.count, &group.spawn) {
            (Some(list), _, _) => {
                list.iter().for_each(&mut cover);
                people += list.len();
            }
            (None, Some(n), Some(region)) => {
                region.iter().for_each(&mut cover);
                people += n;
            }
            _ => {}
        }
    }
    if people == 0 {
        return ([0.0; 2], [0.0; 2], 0);
    }
    (lo, hi, people)
}

/// The people of `scene`, placed among `walls` (the moving bodies' included, where they are at
/// the start) and outside the closed moving bodies, each able to reach its destination on the
/// exits' distance fields. Every failure names the scene field at fault.
pub(crate) fn place_people(
    scene: &Scene,
    walls: &Walls,
    moving: &MovingBodies,
    exits: &Exits,
) -> Result<People, CrowdError> {
    let walkable = |p: [f64; 2]| scene.walkable(p) && !moving.inside(0.0, p);
    // People.
    let mut rng = ChaCha8Rng::seed_from_u64(scene.seed);
    let (lo, hi, people) = placement_box(scene);
    if people >= (1 << 31) {
        return Err(CrowdError::invalid(
            "groups",
            people,
            "at most 2³¹ − 1 people",
        ));
    }
    let mut placed = Placed::new(lo, hi, scene.max_radius(), people);
    let (mut speed, mut group_of, mut place) = (Vec::new(), Vec::new(), Vec::new());
    let mut near = Vec::new();
    let segments = walls.segments();
    let mut clear_of_walls = |p: [f64; 2], r: f64| {
        walls.near(p, r, &mut near);
        near.iter().all(|&w| segments[w as usize].distance(p) >= r)
    };
    for (g, group) in scene.groups.iter().enumerate() {
        let exit = scene
            .exits
            .iter()
            .position(|e| e.name == group.destination)
            .expect("validated");
        let first = placed.pos.len();
        match (&group.positions, group.count, &group.spawn) {
            (Some(list), _, _) => {
                for (k, &p) in list.iter().enumerate() {
                    let r = draw(&group.radius, &mut rng);
                    let field = format!("groups[{g}].positions[{k}]");
                    if !walkable(p) || !clear_of_walls(p, r) {
                        return Err(CrowdError::invalid(
                            field,
                            format!("{p:?}"),
                            format!("a disk of radius {r} there is not inside the walkable area"),
                        ));
                    }
                    if let Some(j) = placed.overlaps(p, r) {
                        return Err(CrowdError::invalid(
                            field,
                            format!("{p:?}"),
                            format!("overlaps the person at {:?}", placed.pos[j]),
                        ));
                    }
                    placed.insert(p, r);
                }
            }
            (None, Some(n), Some(region)) => {
                let region = Polygon {
                    vertices: region.clone(),
                };
                let (rlo, rhi) = region.bounds();
                // The area bound first: n disks of at least the smallest radius cover more than
                // the densest packing of the region can hold, so no number of tries places them.
                let r_min = group.radius.min();
                let need = n as f64 * std::f64::consts::PI * r_min * r_min;
                let room = crate::limits::PACKING * region.area();
                if need > room {
                    let fit = (room / (std::f64::consts::PI * r_min * r_min)).floor();
                    return Err(CrowdError::invalid(
                        format!("groups[{g}].count"),
                        n,
                        format!(
                            "{n} disks of radius ≥ {} m cover {need:.4e} m², more than the \
                             spawn region ({:.4e} m²) holds at the densest packing ({:.1} %: \
                             {room:.4e} m²); at most {fit} {} in the spawn region",
                            moreau_core::Num(r_min),
                            region.area(),
                            100.0 * crate::limits::PACKING,
                            if fit == 1.0 {
                                "person fits"
                            } else {
                                "people fit"
                            }
                        ),
                    ));
                }
                // Then a bounded number of tries: in all, and in a row without a place found.
                let budget = 2000 * n + 10_000;
                const STALL: usize = 1_000_000;
                let (mut made, mut tries, mut missed) = (0, 0, 0);
                // Tries that fell in the region and the walkable area both (for the error).
                let mut inside = 0usize;
                let mut r = draw(&group.radius, &mut rng);
                while made < n && tries < budget && missed < STALL {
                    tries += 1;
                    missed += 1;
                    let p = [
                        rng.random_range(rlo[0]..=rhi[0]),
                        rng.random_range(rlo[1]..=rhi[1]),
                    ];
                    if !(region.contains(p) && walkable(p)) {
                        continue;
                    }
                    inside += 1;
                    if clear_of_walls(p, r) && placed.overlaps(p, r).is_none() {
                        placed.insert(p, r);
                        made += 1;
                        missed = 0;
                        r = draw(&group.radius, &mut rng);
                    }
                }
                if made < n {
                    return Err(CrowdError::invalid(
                        format!("groups[{g}].count"),
                        n,
                        format!(
                            "only {made} people fit in the spawn region ({:.2} m²) after {tries} \
                             random tries{}",
                            region.area(),
                            if inside == 0 {
                                format!(
                                    ": none fell inside both the spawn region and the walkable \
                                     area (does groups[{g}].spawn lie in [area]?)"
                                )
                            } else if missed >= STALL {
                                format!(" ({STALL} in a row found no place)")
                            } else {
                                String::new()
                            }
                        ),
                    ));
                }
            }
            _ => unreachable!("validated"),
        }
        let goal = &exits.exits[exit];
        for k in first..placed.pos.len() {
            let p = placed.pos[k];
            if goal.covers(p, placed.radius[k]) {
                let shape = if goal.area.is_some() {
                    "area"
                } else {
                    "segment"
                };
                return Err(CrowdError::invalid(
                    format!("exits[{exit}].{shape}"),
                    &group.destination,
                    format!(
                        "person {} of groups[{g}] starts at {p:?}, where the exit already counts \
                         them out: everyone there would pass it at the first step (does the \
                         exit cover where people start?)",
                        k - first
                    ),
                ));
            }
            if !exits.fields[exits.goals[exit].exit].distance(p).is_finite() {
                return Err(CrowdError::invalid(
                    format!("groups[{g}].destination"),
                    &group.destination,
                    format!("unreachable from {p:?} (no walkable path on the distance grid)"),
                ));
            }
            speed.push(draw(&group.speed, &mut rng));
            group_of.push(g as u32);
            place.push(Place::ToExit(exit as u32));
        }
    }
    let n = placed.pos.len();
    if n >= (1 << 31) {
        return Err(CrowdError::invalid("groups", n, "at most 2³¹ − 1 people"));
    }
    // People are numbered along a Z-order curve over cells of two radii of their starting
    // positions, so that people who touch sit close in every per-person array and the
    // solver's products read memory nearly in order (1.3× faster at 100,000 people).
    let order = spatial_order(&placed.pos, (2.0 * scene.max_radius()).max(1e-9));
    let q: Vec<f64> = order.iter().flat_map(|&k| placed.pos[k]).collect();
    let ids: Vec<u32> = (0..n as u32).collect();
    let radius: Vec<f64> = order.iter().map(|&k| placed.radius[k]).collect();
    let speed: Vec<f64> = order.iter().map(|&k| speed[k]).collect();
    let group_of: Vec<u32> = order.iter().map(|&k| group_of[k]).collect();
    let place: Vec<Place> = order.iter().map(|&k| place[k]).collect();

    Ok(People::new(ids, q, radius, speed, group_of, place))
}

/// The indices of `pos` sorted along a Z-order (Morton) curve over square cells of side
/// `cell`; ties keep their order.
fn spatial_order(pos: &[[f64; 2]], cell: f64) -> Vec<usize> {
    fn spread(mut x: u64) -> u64 {
        x &= 0xffff_ffff;
        x = (x | (x << 16)) & 0x0000_ffff_0000_ffff;
        x = (x | (x << 8)) & 0x00ff_00ff_00ff_00ff;
        x = (x | (x << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
        x = (x | (x << 2)) & 0x3333_3333_3333_3333;
        (x | (x << 1)) & 0x5555_5555_5555_5555
    }
    let lo = pos
        .iter()
        .fold([f64::INFINITY; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
    let key = |p: &[f64; 2]| {
        let ix = ((p[0] - lo[0]) / cell) as u64;
        let iy = ((p[1] - lo[1]) / cell) as u64;
        spread(ix) | (spread(iy) << 1)
    };
    // Each key computed once, and sorted with its index: the order of a stable sort by key
    // (`sort_by_key` computed both keys at every comparison: 11 % of building a million
    // people's scene).
    let mut keyed: Vec<(u64, u32)> = pos.iter().zip(0..).map(|(p, k)| (key(p), k)).collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, k)| k as usize).collect()
}

#[cfg(test)]
mod tests {
    use super::Placed;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The grid's answer is the brute force's: on a box of fine cells, on a long strip whose
    /// cells the budget coarsens, and for points on the box's far edges.
    #[test]
    fn the_placement_grid_finds_every_overlap_the_brute_force_finds() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for (hi, r_max, people) in [
            ([10.0, 10.0], 0.25, 300),
            ([2000.0, 1.0], 0.2, 200),
            ([0.5, 0.5], 0.3, 5),
        ] {
            let mut placed = Placed::new([0.0, 0.0], hi, r_max, people);
            let (mut pos, mut radius): (Vec<[f64; 2]>, Vec<f64>) = (Vec::new(), Vec::new());
            for t in 0..20 * people {
                let p = if t % 7 == 0 {
                    [hi[0], rng.random_range(0.0..=hi[1])]
                } else {
                    [rng.random_range(0.0..=hi[0]), rng.random_range(0.0..=hi[1])]
                };
                let r = rng.random_range(0.05 * r_max..=r_max);
                let brute = pos.iter().zip(&radius).any(|(q, rq): (&[f64; 2], &f64)| {
                    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt() < r + rq
                });
                let found = placed.overlaps(p, r);
                assert_eq!(found.is_some(), brute, "{p:?} r {r} in {hi:?}");
                if let Some(j) = found {
                    let q = pos[j];
                    assert!(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt() < r + radius[j]);
                } else if pos.len() < people {
                    placed.insert(p, r);
                    pos.push(p);
                    radius.push(r);
                }
            }
            assert!(pos.len() > 1, "{hi:?}");
        }
    }
}
