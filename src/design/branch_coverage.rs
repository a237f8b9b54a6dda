//! Whether a campaign measures the arm in the configurations its work uses
//! (issue #28). The model's unmodelled errors (a transmission error, a
//! backlash) differ between an elbow-up and an elbow-down arm at the same
//! point: a calibration measured in one branch and put to work in another
//! extrapolates, however small the predicted u95 there (which only knows the
//! model). `select` reports, for each branch the work targets use, how many
//! candidates and selected rows share it, and warns when none does.

use crate::robot::ik::branch_of;
use crate::robot::{MAX_JOINTS, Robot};

/// One IK branch the work uses and who shares it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BranchCoverage {
    /// [`crate::robot::ik::IkSolution::branch`] bits.
    pub branch: u8,
    pub targets: usize,
    pub candidates: usize,
    pub selected: usize,
}

/// Per branch of `targets_q` (ascending), the targets, the candidates
/// (`candidates_q`) and the selected candidates (indices into `candidates_q`)
/// in it.
pub fn branch_coverage(
    robot: &Robot,
    targets_q: &[[f64; MAX_JOINTS]],
    candidates_q: &[[f64; MAX_JOINTS]],
    selected: &[usize],
) -> Vec<BranchCoverage> {
    let candidate_branches: Vec<u8> = candidates_q.iter().map(|q| branch_of(robot, q)).collect();
    let target_branches: Vec<u8> = targets_q.iter().map(|q| branch_of(robot, q)).collect();
    let mut branches = target_branches.clone();
    branches.sort_unstable();
    branches.dedup();
    branches
        .into_iter()
        .map(|branch| BranchCoverage {
            branch,
            targets: target_branches.iter().filter(|t| **t == branch).count(),
            candidates: candidate_branches.iter().filter(|c| **c == branch).count(),
            selected: selected
                .iter()
                .filter(|k| candidate_branches.get(**k) == Some(&branch))
                .count(),
        })
        .collect()
}

/// "shoulder front, elbow down, wrist flipped" for the branch bits.
pub fn describe(branch: u8) -> String {
    let shoulder = if branch & 1 != 0 { "back" } else { "front" };
    let elbow = if branch & 2 != 0 { "down" } else { "up" };
    let wrist = if branch & 4 != 0 {
        "flipped"
    } else {
        "not flipped"
    };
    format!("shoulder {shoulder}, elbow {elbow}, wrist {wrist}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::ik;
    use crate::robot::test_support::irb1600;

    /// Two targets solved in two branches; candidates in one of them only.
    #[test]
    fn counts_targets_candidates_and_selected_rows_per_branch() {
        let robot = irb1600();
        let q = [10.0, 20.0, 10.0, 30.0, 40.0, 50.0];
        let solutions = ik::solve(
            &robot,
            &robot.nominal_flange_in_base(&crate::robot::joint_array(&q)),
        )
        .unwrap();
        let first = solutions[0];
        let other = solutions
            .iter()
            .find(|s| s.branch != first.branch)
            .copied()
            .unwrap();
        let coverage = branch_coverage(
            &robot,
            &[first.q_deg, other.q_deg, first.q_deg],
            &[first.q_deg, first.q_deg, first.q_deg],
            &[0, 2],
        );
        let mut expected = vec![
            BranchCoverage {
                branch: first.branch,
                targets: 2,
                candidates: 3,
                selected: 2,
            },
            BranchCoverage {
                branch: other.branch,
                targets: 1,
                candidates: 0,
                selected: 0,
            },
        ];
        expected.sort_by_key(|c| c.branch);
        assert_eq!(coverage, expected);
        assert_eq!(describe(6), "shoulder front, elbow down, wrist flipped");
    }
}
