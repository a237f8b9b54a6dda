//! Positioner configurations at which the tracker sees a nest (issue #30).
//!
//! An SMR sitting in a nest on the positioner's table returns the beam only
//! within its acceptance angle of the nest's axis, which is the table's
//! normal. Before the calibration the nests' positions on the table are not
//! known, so the table's origin stands for them: a nest a few hundred
//! millimetres off it, seen from a tracker metres away, is off by a few
//! degrees. Configurations are drawn uniformly within the axes' limits (the
//! turn spread over its whole range moves every positioner term) and kept
//! where the normal faces the tracker.

use nalgebra::Vector3;
use rand::Rng;

use crate::robot::positioner::{MAX_POSITIONER_AXES, PositionerModel};

/// What a nest must see.
#[derive(Debug, Clone, Copy)]
pub struct NestView {
    /// The tracker head, robot base frame (mm).
    pub tracker_mm: Vector3<f64>,
    /// Largest angle between the table's normal and the direction from the
    /// table's origin to the tracker (deg).
    pub acceptance_half_angle_deg: f64,
}

impl NestView {
    /// Angle (deg) between the table's normal at axis values `p_deg` and the
    /// direction to the tracker.
    pub fn angle_deg(
        &self,
        positioner: &PositionerModel,
        p_deg: &[f64; MAX_POSITIONER_AXES],
    ) -> f64 {
        let table = positioner.chain(p_deg).table();
        let normal = table.rotation.column(2).into_owned();
        let to_tracker = self.tracker_mm - table.origin_mm;
        normal.angle(&to_tracker).to_degrees()
    }

    /// Whether the tracker sees a nest at axis values `p_deg`.
    pub fn sees(&self, positioner: &PositionerModel, p_deg: &[f64; MAX_POSITIONER_AXES]) -> bool {
        self.angle_deg(positioner, p_deg) <= self.acceptance_half_angle_deg
    }
}

/// Up to `wanted` configurations the tracker sees, drawn uniformly within
/// `limits_deg` (one `[min, max]` per axis; a missing second axis stays at
/// 0) in at most `max_draws` draws, and the draws made.
pub fn draw_configurations(
    positioner: &PositionerModel,
    limits_deg: &[[f64; 2]],
    view: &NestView,
    wanted: usize,
    max_draws: usize,
    rng: &mut impl Rng,
) -> (Vec<[f64; MAX_POSITIONER_AXES]>, usize) {
    let mut kept = Vec::with_capacity(wanted);
    let mut draws = 0;
    while kept.len() < wanted && draws < max_draws {
        draws += 1;
        let mut p_deg = [0.0; MAX_POSITIONER_AXES];
        for (value, [lo, hi]) in p_deg.iter_mut().zip(limits_deg) {
            *value = rng.random_range(*lo..=*hi);
        }
        if view.sees(positioner, &p_deg) {
            kept.push(p_deg);
        }
    }
    (kept, draws)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::ParamValues;
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    /// The shipped tilt-and-turn positioner: at tilt 0 its table's normal
    /// stands vertical, so a tracker far straight above sees the nests at
    /// any turn, and one level with the table sees none of them then.
    #[test]
    fn the_table_s_normal_decides_what_the_tracker_sees() {
        let robot = crate::robot::test_support::irb1600_with_positioner();
        let prepared = robot.prepare(&ParamValues::nominal(robot.spec()));
        let positioner = prepared.positioner.as_ref().unwrap();
        let table = positioner.chain(&[0.0, 0.0]).table();
        let above = NestView {
            tracker_mm: table.origin_mm + Vector3::new(0.0, 0.0, 1e7),
            acceptance_half_angle_deg: 40.0,
        };
        for turn in [-300.0, -45.0, 0.0, 120.0] {
            assert!(above.angle_deg(positioner, &[0.0, turn]) < 1e-3);
        }
        // Tilted by 30° the normal is 30° off the vertical.
        assert!((above.angle_deg(positioner, &[30.0, 77.0]) - 30.0).abs() < 1e-3);
        assert!(!above.sees(positioner, &[50.0, 0.0]));
        let level = NestView {
            tracker_mm: table.origin_mm + Vector3::new(2000.0, 0.0, 0.0),
            acceptance_half_angle_deg: 40.0,
        };
        assert!((level.angle_deg(positioner, &[0.0, 10.0]) - 90.0).abs() < 1e-9);

        let limits = [[-90.0, 90.0], [-360.0, 360.0]];
        let mut rng = StdRng::seed_from_u64(7);
        let (kept, draws) = draw_configurations(positioner, &limits, &above, 50, 10_000, &mut rng);
        assert_eq!(kept.len(), 50);
        assert!(draws > 50, "some draws tilt too far");
        assert!(kept.iter().all(|p| p[0].abs() <= 40.0 + 1e-3));
        let turns = kept.iter().map(|p| p[1]);
        let (lo, hi) = turns.fold((f64::MAX, f64::MIN), |(lo, hi), t| (lo.min(t), hi.max(t)));
        assert!(
            lo < -200.0 && hi > 200.0,
            "turns spread over the range: {lo} {hi}"
        );
    }
}
