//! The direction in which each joint last moved before a reading (spec §8,
//! `dir1 … dir6`). Gear backlash puts a joint on one side of its dead band or
//! the other depending on it, so a model with backlash needs it per row, and
//! a simulated robot with backlash must apply the same one.
//!
//! A campaign measures its rows in order, so a row's direction follows from
//! the commands alone: the sign of its joint change from the previous row,
//! or, where the joint did not move, the previous row's direction (it stays
//! on the side it was pushed to); 0 where nothing is known yet (the first
//! row). Derived from the commands, it is the same in an interrupted and
//! resumed campaign as in an uninterrupted one.

use crate::robot::MAX_JOINTS;

/// Joint changes below this (deg) are no move: a joint commanded to where it
/// is keeps the side of its dead band.
const NO_MOVE_DEG: f64 = 1e-9;

/// The direction of the move from `previous` to `current`, joints that do not
/// move keeping `carried`.
pub fn step_direction(
    previous: Option<&[f64; MAX_JOINTS]>,
    current: &[f64; MAX_JOINTS],
    carried: [i8; MAX_JOINTS],
) -> [i8; MAX_JOINTS] {
    let Some(previous) = previous else {
        return carried;
    };
    std::array::from_fn(|j| {
        let change = current[j] - previous[j];
        if change > NO_MOVE_DEG {
            1
        } else if change < -NO_MOVE_DEG {
            -1
        } else {
            carried[j]
        }
    })
}

/// The approach direction of every row of a campaign measured in this order.
pub fn approach_directions(q_deg: &[[f64; MAX_JOINTS]]) -> Vec<[i8; MAX_JOINTS]> {
    let mut carried = [0i8; MAX_JOINTS];
    let mut previous: Option<&[f64; MAX_JOINTS]> = None;
    q_deg
        .iter()
        .map(|q| {
            carried = step_direction(previous, q, carried);
            previous = Some(q);
            carried
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand-worked: joint 1 rises then holds (keeps +1), joint 2 falls, joint 3
    /// never moves (0 throughout), the first row knows nothing.
    #[test]
    fn signs_of_the_moves_carried_over_where_a_joint_holds() {
        let rows = [
            [0.0, 10.0, 5.0, 0.0, 0.0, 0.0, 0.0],
            [1.0, 9.0, 5.0, 0.0, 0.0, 0.0, 0.0],
            [1.0, 8.0, 5.0, -1.0, 0.0, 0.0, 0.0],
            [1.0, 8.5, 5.0, -1.0, 0.0, 0.0, 0.0],
        ];
        assert_eq!(
            approach_directions(&rows),
            vec![
                [0, 0, 0, 0, 0, 0, 0],
                [1, -1, 0, 0, 0, 0, 0],
                [1, -1, 0, -1, 0, 0, 0],
                [1, 1, 0, -1, 0, 0, 0],
            ]
        );
    }
}
