//! The one attribute-group type: the bitstream's [`Group`] (SPEC §6), as the encoder uses it —
//! where a group's values sit in a [`Splats`], its step in [`Steps`], and [`GroupMap`], one value
//! per group (steps, gradients, moments, learning rates, report rows).
//!
//! Every parameter of a scene belongs to exactly one group: the SH rest coefficients of band `b`
//! are group `Sh{b}` (per Gaussian a contiguous run of `(2b+1)·3` values of `Splats::sh_rest`).

use std::ops::{Index, IndexMut, Range};

use gscodec_decoder::Splats;
use serde::ser::SerializeMap;
use serde::Serialize;

pub use gscodec_decoder::Group;

use super::quantise::Steps;

/// One `T` per attribute group, indexed by [`Group`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GroupMap<T>(pub [T; 8]);

impl<T> GroupMap<T> {
    /// The map with `f(g)` for every group `g`.
    pub fn from_fn(mut f: impl FnMut(Group) -> T) -> Self {
        GroupMap(Group::ALL.map(&mut f))
    }

    /// `(group, value)` in [`Group::ALL`] order.
    pub fn iter(&self) -> impl Iterator<Item = (Group, &T)> {
        Group::ALL.into_iter().zip(self.0.iter())
    }

    /// The map with `f` applied to every value.
    pub fn map<U>(self, f: impl FnMut(T) -> U) -> GroupMap<U> {
        GroupMap(self.0.map(f))
    }
}

impl<T> Index<Group> for GroupMap<T> {
    type Output = T;
    fn index(&self, g: Group) -> &T {
        &self.0[g as usize]
    }
}

impl<T> IndexMut<Group> for GroupMap<T> {
    fn index_mut(&mut self, g: Group) -> &mut T {
        &mut self.0[g as usize]
    }
}

/// Serialised as an object keyed by [`Group::name`].
impl<T: Serialize> Serialize for GroupMap<T> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(8))?;
        for (g, v) in self.iter() {
            m.serialize_entry(g.name(), v)?;
        }
        m.end()
    }
}

/// Where group `g`'s values sit in a scene of SH degree `degree`: `(stride, range)` such that
/// Gaussian `i`'s values are `field[i·stride..][range]` of the field [`values`] returns.
/// Position has 3 values (x, y, z) and Rotation 4 (the quaternion), unlike the coded channel
/// counts of [`Group::channels`]; a band above `degree` has none (`stride` 0).
pub fn layout(g: Group, degree: u8) -> (usize, Range<usize>) {
    match g {
        Group::Position | Group::Scale | Group::ShDc => (3, 0..3),
        Group::Rotation => (4, 0..4),
        Group::Opacity => (1, 0..1),
        _ => {
            let b = usize::from(g.sh_band());
            if g.sh_band() > degree {
                return (0, 0..0);
            }
            let k = (usize::from(degree) + 1).pow(2) - 1;
            let first = (b * b - 1) * 3;
            (k * 3, first..first + (2 * b + 1) * 3)
        }
    }
}

/// The field of `s` holding group `g` (all SH bands share `sh_rest`); see [`layout`].
pub fn values(s: &Splats, g: Group) -> &[f32] {
    match g {
        Group::Position => s.positions.as_flattened(),
        Group::Scale => s.log_scales.as_flattened(),
        Group::Rotation => s.rotations.as_flattened(),
        Group::Opacity => &s.opacity_logits,
        Group::ShDc => s.sh_dc.as_flattened(),
        Group::Sh1 | Group::Sh2 | Group::Sh3 => &s.sh_rest,
    }
}

/// [`values`], mutable.
pub fn values_mut(s: &mut Splats, g: Group) -> &mut [f32] {
    match g {
        Group::Position => s.positions.as_flattened_mut(),
        Group::Scale => s.log_scales.as_flattened_mut(),
        Group::Rotation => s.rotations.as_flattened_mut(),
        Group::Opacity => &mut s.opacity_logits,
        Group::ShDc => s.sh_dc.as_flattened_mut(),
        Group::Sh1 | Group::Sh2 | Group::Sh3 => &mut s.sh_rest,
    }
}

/// Group `g`'s values of each Gaussian in turn (one slice per Gaussian; none for a band above
/// the scene's degree).
pub fn per_gaussian(s: &Splats, g: Group) -> impl Iterator<Item = &[f32]> {
    let (stride, r) = layout(g, s.sh_degree);
    values(s, g).chunks_exact(stride.max(1)).take(if stride == 0 { 0 } else { s.len() }).map(move |v| &v[r.clone()])
}

/// Index into [`values`] of value `c` (0-based within the group) of Gaussian `i`.
pub fn index(g: Group, degree: u8, i: usize, c: usize) -> usize {
    let (stride, r) = layout(g, degree);
    i * stride + r.start + c
}

/// Groups with values in a scene of SH degree `degree`.
pub fn present(degree: u8) -> impl Iterator<Item = Group> {
    Group::present(degree)
}

impl Steps {
    /// The step of group `g`: the quantisation bin of its values, except Position, whose entry
    /// is `position_rel` (the grid step relative to the scene's 10th-percentile Gaussian size).
    pub fn of(&self, g: Group) -> f32 {
        match g {
            Group::Position => self.position_rel,
            Group::Scale => self.scale,
            Group::Rotation => self.rotation,
            Group::Opacity => self.opacity,
            Group::ShDc => self.sh_dc,
            _ => self.sh_rest[usize::from(g.sh_band()) - 1],
        }
    }

    /// [`Steps::of`], mutable.
    pub fn of_mut(&mut self, g: Group) -> &mut f32 {
        match g {
            Group::Position => &mut self.position_rel,
            Group::Scale => &mut self.scale,
            Group::Rotation => &mut self.rotation,
            Group::Opacity => &mut self.opacity,
            Group::ShDc => &mut self.sh_dc,
            _ => &mut self.sh_rest[usize::from(g.sh_band()) - 1],
        }
    }

    /// Every group's step ([`Steps::of`]).
    pub fn map(&self) -> GroupMap<f32> {
        GroupMap::from_fn(|g| self.of(g))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_value_of_a_scene_is_in_exactly_one_group() {
        for degree in 0..=3u8 {
            let mut s = Splats::new(degree);
            let k3 = s.rest_coeffs() * 3;
            s.push([1.0; 3], [2.0; 3], [3.0; 4], 4.0, [5.0; 3], &vec![6.0; k3]);
            s.push([1.0; 3], [2.0; 3], [3.0; 4], 4.0, [5.0; 3], &vec![6.0; k3]);
            let mut seen = s.clone();
            for g in Group::ALL {
                let r = layout(g, degree).1;
                for i in 0..2 {
                    for c in 0..r.len() {
                        let v = &mut values_mut(&mut seen, g)[index(g, degree, i, c)];
                        assert!(*v != 0.0, "{g:?} value {c} of Gaussian {i} claimed twice");
                        *v = 0.0;
                    }
                }
            }
            for g in Group::ALL {
                assert!(values(&seen, g).iter().all(|&v| v == 0.0), "degree {degree}: {g:?} has unclaimed values");
            }
            // per_gaussian yields exactly the group's values of each Gaussian.
            for g in Group::ALL {
                let n: usize = per_gaussian(&s, g).map(<[f32]>::len).sum();
                assert_eq!(n, 2 * layout(g, degree).1.len(), "degree {degree}: {g:?}");
                assert_eq!(per_gaussian(&s, g).count(), if g.sh_band() > degree { 0 } else { 2 });
            }
            // SH band widths are the coded channel counts.
            for g in present(degree).filter(|g| g.sh_band() > 0) {
                assert_eq!(layout(g, degree).1.len(), g.channels());
            }
        }
    }

    #[test]
    fn steps_are_indexed_by_group() {
        let mut s = Steps::default();
        for (k, g) in Group::ALL.into_iter().enumerate() {
            *s.of_mut(g) = k as f32 + 1.0;
        }
        assert_eq!(s.sh_rest, [6.0, 7.0, 8.0]);
        assert_eq!((s.position_rel, s.scale, s.rotation, s.opacity, s.sh_dc), (1.0, 2.0, 3.0, 4.0, 5.0));
        assert_eq!(s.map().0, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
        let json = serde_json::to_string(&s.map()).unwrap();
        assert!(json.starts_with(r#"{"position":1.0,"scale":2.0"#) && json.ends_with(r#""sh_band3":8.0}"#), "{json}");
    }
}
