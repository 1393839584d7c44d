//! Objects seen during the mission's FIND steps, remembered where they
//! stood: a later FIND looks for its target there first.

use nalgebra::Vector2;

use super::REFERENCE_SAME_M;
use crate::executor::model::*;

/// Places of objects seen during the mission's FIND steps kept at most;
/// the least seen is forgotten first.
const LANDMARK_PLACES: usize = 64;

/// Where an object stood when a FIND step saw it: the footprints of a
/// class's boxes within `REFERENCE_SAME_M` of each other are one object,
/// at their running mean.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Landmark {
    pub(crate) class_id: i32,
    /// Odom, on the floor.
    pub(crate) at: Vector2<f64>,
    /// Frames a box of the class stood there.
    pub(crate) sightings: u32,
    /// The plan step that saw it last.
    pub(crate) step: usize,
}

/// Adds this frame's footprints (`class`, odom) seen by step `step` to `landmarks`.
pub(super) fn remember_landmarks(
    landmarks: &mut Vec<Landmark>,
    seen: impl IntoIterator<Item = (i32, Vector2<f64>)>,
    step: usize,
) {
    for (class_id, at) in seen {
        let same = landmarks
            .iter_mut()
            .filter(|l| l.class_id == class_id && (l.at - at).norm() <= REFERENCE_SAME_M)
            .min_by(|a, b| (a.at - at).norm().total_cmp(&(b.at - at).norm()));
        match same {
            Some(l) => {
                l.sightings = l.sightings.saturating_add(1);
                l.at += (at - l.at) / f64::from(l.sightings);
                l.step = step;
            }
            None => {
                if landmarks.len() == LANDMARK_PLACES
                    && let Some(i) = (0..landmarks.len()).min_by_key(|&i| (landmarks[i].sightings, landmarks[i].step))
                {
                    landmarks.swap_remove(i);
                }
                landmarks.push(Landmark { class_id, at, sightings: 1, step });
            }
        }
    }
}

/// The place to look for a `class_id` target first when step `step` does
/// not see it: the nearest to `pose` of the objects of that class an
/// earlier step saw in at least `min_sightings` frames (one stray box — a
/// false positive — is not a place).
pub(crate) fn remembered(
    landmarks: &[Landmark],
    class_id: i32,
    step: usize,
    min_sightings: u32,
    pose: Pose2,
) -> Option<Vector2<f64>> {
    let here = Vector2::new(pose.x, pose.y);
    landmarks
        .iter()
        .filter(|l| l.class_id == class_id && l.step < step && l.sightings >= min_sightings)
        .map(|l| l.at)
        .min_by(|a, b| (a - here).norm().total_cmp(&(b - here).norm()))
}

#[cfg(test)]
#[path = "landmarks_tests.rs"]
mod tests;
