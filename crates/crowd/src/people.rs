//! `People`: the one owner of every person's data (id, position, radius, desired speed, group,
//! where they are); everything else borrows it.

use serde::{Deserialize, Serialize};

/// Where a person is headed (people who leave the scene are no longer in [`People`]; their
/// [`ExitRecord`] stays).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Place {
    /// Inside, walking to exit `e`.
    ToExit(u32),
    /// Passed exit `e`, walking to its target area.
    ToTarget(u32),
    /// Inside the target area of exit `e`: standing.
    Arrived(u32),
}

/// A person passing an exit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExitRecord {
    /// The person.
    pub id: u32,
    /// The exit (its index in the scene).
    pub exit: u32,
    /// When (s): the end of the step in which they reached it.
    pub t: f64,
}

/// The people present, as one struct of arrays indexed alike; ids increase along the arrays
/// (people are numbered along a space-filling curve of their starting positions, leaving
/// keeps the order, and people who enter later get the next ids and go at the end).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct People {
    id: Vec<u32>,
    position: Vec<f64>,
    radius: Vec<f64>,
    speed: Vec<f64>,
    group: Vec<u32>,
    place: Vec<Place>,
}

/// Everything about the people but their positions, borrowed (the positions are the state the
/// scheme moves, borrowed mutably beside it).
#[derive(Debug, Clone, Copy)]
pub struct PeopleView<'a> {
    /// Ids.
    pub id: &'a [u32],
    /// Radii (m).
    pub radius: &'a [f64],
    /// Desired speeds (m/s).
    pub speed: &'a [f64],
    /// Index of each person's group: the scene's groups, then one per inflow source.
    pub group: &'a [u32],
    /// Where each is headed.
    pub place: &'a [Place],
}

impl People {
    /// People from per-person arrays of equal length; positions are `[x0, y0, x1, y1, …]`.
    ///
    /// # Panics
    /// If the lengths differ or the ids do not increase (a bug in the caller).
    pub fn new(
        id: Vec<u32>,
        position: Vec<f64>,
        radius: Vec<f64>,
        speed: Vec<f64>,
        group: Vec<u32>,
        place: Vec<Place>,
    ) -> Self {
        let n = id.len();
        assert!(
            position.len() == 2 * n
                && radius.len() == n
                && speed.len() == n
                && group.len() == n
                && place.len() == n,
            "per-person arrays of different lengths"
        );
        assert!(id.windows(2).all(|w| w[0] < w[1]), "ids must increase");
        Self {
            id,
            position,
            radius,
            speed,
            group,
            place,
        }
    }

    /// How many people are present.
    pub fn len(&self) -> usize {
        self.id.len()
    }

    /// True when nobody is present.
    pub fn is_empty(&self) -> bool {
        self.id.is_empty()
    }

    /// Ids.
    pub fn ids(&self) -> &[u32] {
        &self.id
    }

    /// Positions `[x0, y0, x1, y1, …]` (m).
    pub fn positions(&self) -> &[f64] {
        &self.position
    }

    /// Radii (m).
    pub fn radii(&self) -> &[f64] {
        &self.radius
    }

    /// Desired speeds (m/s).
    pub fn speeds(&self) -> &[f64] {
        &self.speed
    }

    /// Index of each person's group: `0..groups` the scene's groups, `groups + s` the people
    /// of inflow source `s`.
    pub fn groups(&self) -> &[u32] {
        &self.group
    }

    /// Where each is headed.
    pub fn places(&self) -> &[Place] {
        &self.place
    }

    /// The position of the person at index `i`.
    pub fn position(&self, i: usize) -> [f64; 2] {
        [self.position[2 * i], self.position[2 * i + 1]]
    }

    /// The index of the person with id `id`, if present.
    pub fn index_of(&self, id: u32) -> Option<usize> {
        self.id.binary_search(&id).ok()
    }

    /// Everything but the positions.
    pub fn view(&self) -> PeopleView<'_> {
        PeopleView {
            id: &self.id,
            radius: &self.radius,
            speed: &self.speed,
            group: &self.group,
            place: &self.place,
        }
    }

    /// The positions, mutably, beside everything else.
    pub fn split_mut(&mut self) -> (&mut [f64], PeopleView<'_>) {
        (
            &mut self.position,
            PeopleView {
                id: &self.id,
                radius: &self.radius,
                speed: &self.speed,
                group: &self.group,
                place: &self.place,
            },
        )
    }

    /// Sets where person `i` is headed.
    pub(crate) fn set_place(&mut self, i: usize, place: Place) {
        self.place[i] = place;
    }

    /// Adds a person at the end, with an id above every id so far: the one place where
    /// per-person arrays grow.
    ///
    /// # Panics
    /// If `id` is not above the last id (a bug in the caller).
    pub(crate) fn push(
        &mut self,
        id: u32,
        position: [f64; 2],
        radius: f64,
        speed: f64,
        group: u32,
        place: Place,
    ) {
        assert!(
            self.id.last().is_none_or(|&last| last < id),
            "ids must increase"
        );
        self.id.push(id);
        self.position.extend_from_slice(&position);
        self.radius.push(radius);
        self.speed.push(speed);
        self.group.push(group);
        self.place.push(place);
    }

    /// Keeps the people whose `keep` is true, in order: the one place where per-person arrays
    /// shrink.
    pub(crate) fn retain(&mut self, keep: &[bool]) {
        fn retain<T>(v: &mut Vec<T>, keep: &[bool], width: usize) {
            let mut k = 0;
            v.retain(|_| {
                let stay = keep[k / width];
                k += 1;
                stay
            });
        }
        retain(&mut self.id, keep, 1);
        retain(&mut self.position, keep, 2);
        retain(&mut self.radius, keep, 1);
        retain(&mut self.speed, keep, 1);
        retain(&mut self.group, keep, 1);
        retain(&mut self.place, keep, 1);
    }

    /// Checks that `self` is a consistent set of people of dimension `2 len` (for restored
    /// states), naming the first inconsistency.
    pub(crate) fn check(&self) -> Result<(), String> {
        let n = self.id.len();
        if self.position.len() != 2 * n
            || self.radius.len() != n
            || self.speed.len() != n
            || self.group.len() != n
            || self.place.len() != n
        {
            return Err("per-person arrays of different lengths".into());
        }
        if !self.id.windows(2).all(|w| w[0] < w[1]) {
            return Err("ids do not increase".into());
        }
        if let Some(i) = self.position.iter().position(|x| !x.is_finite()) {
            return Err(format!("non-finite position of person index {}", i / 2));
        }
        // The bound a scene's coordinates follow: beyond it a step's distances lose every
        // digit of a person's size, and its contact data overflow.
        let far = crate::scene::limits::MAX_COORDINATE;
        if let Some((i, x)) = (self.position.iter().enumerate()).find(|(_, x)| x.abs() > far) {
            return Err(format!(
                "position coordinate {x:e} of person index {}: must be within ±{far:e} m \
                 (the limit of a scene)",
                i / 2
            ));
        }
        // The rules a scene's groups follow (finite radii > 0, finite speeds ≥ 0).
        if let Some((i, r)) =
            (self.radius.iter().enumerate()).find(|(_, r)| !(r.is_finite() && **r > 0.0))
        {
            return Err(format!(
                "radius {} of person index {i}: must be finite and > 0",
                moreau_core::Num(*r)
            ));
        }
        if let Some((i, v)) =
            (self.speed.iter().enumerate()).find(|(_, v)| !(v.is_finite() && **v >= 0.0))
        {
            return Err(format!(
                "desired speed {} of person index {i}: must be finite and ≥ 0",
                moreau_core::Num(*v)
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn retain_and_push_keep_every_array_aligned() {
        let mut p = People::new(
            vec![1, 4, 7],
            vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5],
            vec![0.1, 0.2, 0.3],
            vec![1.0, 1.1, 1.2],
            vec![0, 1, 0],
            vec![Place::ToExit(0), Place::ToTarget(0), Place::Arrived(1)],
        );
        p.retain(&[true, false, true]);
        p.push(9, [3.0, 3.5], 0.4, 1.3, 2, Place::ToExit(0));
        assert_eq!(p.ids(), &[1, 7, 9]);
        assert_eq!(p.positions(), &[0.0, 0.5, 2.0, 2.5, 3.0, 3.5]);
        assert_eq!(p.radii(), &[0.1, 0.3, 0.4]);
        assert_eq!(p.speeds(), &[1.0, 1.2, 1.3]);
        assert_eq!(p.groups(), &[0, 0, 2]);
        assert_eq!(
            p.places(),
            &[Place::ToExit(0), Place::Arrived(1), Place::ToExit(0)]
        );
        assert_eq!(p.index_of(7), Some(1));
        assert_eq!(p.view().group, &[0, 0, 2]);
        assert_eq!(p.index_of(4), None);
        assert!(p.check().is_ok());
    }
}
