//! Placing a scene's people: fixed positions or random draws without overlap, checked against
//! walls and each other, then numbered along a space-filling curve.

use std::collections::HashMap;

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

/// Overlap test against people already placed, through a hash of cells of side `2 r_max`.
struct Placed {
    cell: f64,
    cells: HashMap<(i64, i64), Vec<usize>>,
    pos: Vec<[f64; 2]>,
    radius: Vec<f64>,
}

impl Placed {
    fn key(&self, p: [f64; 2]) -> (i64, i64) {
        (
            (p[0] / self.cell).floor() as i64,
            (p[1] / self.cell).floor() as i64,
        )
    }
    fn overlaps(&self, p: [f64; 2], r: f64) -> Option<usize> {
        let (cx, cy) = self.key(p);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &j in self
                    .cells
                    .get(&(cx + dx, cy + dy))
                    .map_or(&[][..], |v| v.as_slice())
                {
                    let q = self.pos[j];
                    if ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt() < r + self.radius[j] {
                        return Some(j);
                    }
                }
            }
        }
        None
    }
    fn insert(&mut self, p: [f64; 2], r: f64) {
        let k = self.key(p);
        self.cells.entry(k).or_default().push(self.pos.len());
        self.pos.push(p);
        self.radius.push(r);
    }
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
    let mut placed = Placed {
        cell: (2.0 * scene.max_radius()).max(1e-9),
        cells: HashMap::new(),
        pos: Vec::new(),
        radius: Vec::new(),
    };
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
            if goal.reached(p, placed.radius[k]) {
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
    let order = spatial_order(&placed.pos, placed.cell);
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
    let mut order: Vec<usize> = (0..pos.len()).collect();
    order.sort_by_key(|&k| key(&pos[k]));
    order
}
