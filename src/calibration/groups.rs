//! Groups of rows for held-out validation (issue #28): rows that stand or fall
//! together, so a fold leaves out a whole region of the work instead of every
//! other row.
//!
//! A random split validates a calibration on rows drawn from the same poses it
//! was fitted on; a robot put to work goes where the campaign did not. Grouping
//! the rows and leaving whole groups out asks the harder question: how good is
//! the calibration a little away from its rows?
//!
//! * [`Grouping::Region`]: blocks of the workspace, k-means on the measured
//!   positions (mm);
//! * [`Grouping::Configuration`]: clusters in joint space, k-means on the cosine
//!   and sine of every joint angle (so −180° and +180° are neighbours); arm
//!   branches lie far apart in that space and fall in different clusters;
//! * [`Grouping::Load`]: bins of the wrench, k-means on the force (N) and moment
//!   (N·m) each divided by its largest magnitude over the rows, so both count;
//! * [`Grouping::Time`]: consecutive blocks of equal row counts in order of the
//!   measurement time;
//! * [`Grouping::Random`]: every row its own group (plain k-fold).
//!
//! k-means is Lloyd's iteration from a k-means++ start drawn with the caller's
//! seed, fitted on at most [`KMEANS_SAMPLE_ROWS`] rows (a fixed stride) and then
//! applied to every row, so a million rows group in a pass. Groups are then
//! dealt to folds whole ([`folds_of_groups`]), largest first, each to the fold
//! with the fewest rows so far: deterministic, and the folds as even as whole
//! groups allow.

use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::robot::ConfWrench;

/// Rows k-means fits its centres on at most; the rest are only assigned.
pub const KMEANS_SAMPLE_ROWS: usize = 20_000;

/// Lloyd iterations at most; they stop earlier when no row changes cluster.
const KMEANS_ITERATIONS: usize = 100;

/// How rows are grouped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Grouping {
    /// Every row its own group: plain k-fold, the optimistic figure.
    Random,
    /// Blocks of the workspace (k-means on the measured positions).
    Region,
    /// Clusters in joint space (k-means on cos and sin of the joint angles).
    Configuration,
    /// Bins of the wrench's magnitude and direction (k-means on the scaled wrench).
    Load,
    /// Consecutive blocks in order of `measured_at`.
    Time,
}

impl Grouping {
    pub fn as_str(self) -> &'static str {
        match self {
            Grouping::Random => "random",
            Grouping::Region => "region",
            Grouping::Configuration => "configuration",
            Grouping::Load => "load",
            Grouping::Time => "time",
        }
    }
}

impl std::fmt::Display for Grouping {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why rows cannot be grouped as asked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GroupError {
    #[error("{rows} row(s) cannot make {groups} groups")]
    TooFewRows { rows: usize, groups: usize },
    #[error("grouping by time needs the column `measured_at`")]
    NoTimes,
    #[error("grouping by load needs rows with different wrenches; every row carries the same one")]
    OneLoad,
    #[error(
        "the rows fall in only {found} distinct group(s) by {grouping}; {wanted} folds need at least {wanted}"
    )]
    TooFewGroups {
        grouping: Grouping,
        found: usize,
        wanted: usize,
    },
}

/// What grouping may look at, one entry per row.
pub struct GroupInput<'a> {
    pub rows: &'a [ConfWrench],
    pub positions_mm: &'a [Vector3<f64>],
    /// Microseconds since the epoch, where the table has `measured_at`.
    pub measured_at_us: Option<&'a [i64]>,
}

/// The group (0..groups) of every row. `groups` is ignored for `Random` (each
/// row its own group).
pub fn group_rows(
    grouping: Grouping,
    input: &GroupInput<'_>,
    groups: usize,
    seed: u64,
) -> Result<Vec<usize>, GroupError> {
    let n = input.rows.len();
    if grouping != Grouping::Random && (n < groups || groups == 0) {
        return Err(GroupError::TooFewRows { rows: n, groups });
    }
    match grouping {
        Grouping::Random => Ok((0..n).collect()),
        Grouping::Time => {
            let times = input.measured_at_us.ok_or(GroupError::NoTimes)?;
            let mut order: Vec<usize> = (0..n).collect();
            // Stable: rows measured at the same time keep their table order.
            order.sort_by_key(|k| times[*k]);
            let mut group = vec![0; n];
            for (rank, k) in order.iter().enumerate() {
                group[*k] = rank * groups / n;
            }
            Ok(group)
        }
        Grouping::Region => {
            let points: Vec<Vec<f64>> = input
                .positions_mm
                .iter()
                .map(|p| vec![p.x, p.y, p.z])
                .collect();
            Ok(kmeans(&points, groups, seed))
        }
        Grouping::Configuration => {
            let points: Vec<Vec<f64>> = input
                .rows
                .iter()
                .map(|row| {
                    row.q_deg
                        .iter()
                        .flat_map(|q| {
                            let q = q.to_radians();
                            [q.cos(), q.sin()]
                        })
                        .collect()
                })
                .collect();
            Ok(kmeans(&points, groups, seed))
        }
        Grouping::Load => {
            let largest =
                |f: &dyn Fn(&ConfWrench) -> f64| input.rows.iter().map(f).fold(0.0_f64, f64::max);
            let force_scale = largest(&|r| r.wrench.force_n.norm());
            let moment_scale = largest(&|r| r.wrench.moment_nm.norm());
            let first = input.rows[0].wrench;
            if input.rows.iter().all(|r| r.wrench == first) {
                return Err(GroupError::OneLoad);
            }
            let scaled = |v: Vector3<f64>, scale: f64| {
                if scale > 0.0 { v / scale } else { v }
            };
            let points: Vec<Vec<f64>> = input
                .rows
                .iter()
                .map(|r| {
                    let f = scaled(r.wrench.force_n, force_scale);
                    let m = scaled(r.wrench.moment_nm, moment_scale);
                    vec![f.x, f.y, f.z, m.x, m.y, m.z]
                })
                .collect();
            Ok(kmeans(&points, groups, seed))
        }
    }
}

/// Squared Euclidean distance.
fn distance2(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// The nearest of `centres` to `point` (lowest index on ties).
fn nearest(point: &[f64], centres: &[Vec<f64>]) -> usize {
    let mut best = (0, f64::INFINITY);
    for (c, centre) in centres.iter().enumerate() {
        let d = distance2(point, centre);
        if d < best.1 {
            best = (c, d);
        }
    }
    best.0
}

/// k-means labels (0..k) of `points`: centres fitted on a strided sample,
/// every point assigned to its nearest. Clusters are renumbered by their
/// first row so the labels do not depend on the random start's order.
fn kmeans(points: &[Vec<f64>], k: usize, seed: u64) -> Vec<usize> {
    let stride = points.len().div_ceil(KMEANS_SAMPLE_ROWS).max(1);
    let sample: Vec<&Vec<f64>> = points.iter().step_by(stride).collect();
    let mut rng = StdRng::seed_from_u64(seed);
    // k-means++: each next centre drawn with probability ∝ squared distance.
    let mut centres: Vec<Vec<f64>> = vec![sample[rng.random_range(0..sample.len())].clone()];
    let mut d2: Vec<f64> = sample.iter().map(|p| distance2(p, &centres[0])).collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        let next = if total > 0.0 {
            let mut pick = rng.random::<f64>() * total;
            let mut chosen = sample.len() - 1;
            for (i, d) in d2.iter().enumerate() {
                if pick < *d {
                    chosen = i;
                    break;
                }
                pick -= d;
            }
            chosen
        } else {
            rng.random_range(0..sample.len())
        };
        centres.push(sample[next].clone());
        for (i, p) in sample.iter().enumerate() {
            d2[i] = d2[i].min(distance2(p, &centres[centres.len() - 1]));
        }
    }
    let mut labels = vec![usize::MAX; sample.len()];
    for _ in 0..KMEANS_ITERATIONS {
        let mut changed = false;
        for (i, p) in sample.iter().enumerate() {
            let c = nearest(p, &centres);
            if labels[i] != c {
                labels[i] = c;
                changed = true;
            }
        }
        if !changed {
            break;
        }
        let dims = centres[0].len();
        let mut sums = vec![vec![0.0; dims]; k];
        let mut counts = vec![0usize; k];
        for (p, c) in sample.iter().zip(&labels) {
            counts[*c] += 1;
            for (s, x) in sums[*c].iter_mut().zip(p.iter()) {
                *s += x;
            }
        }
        for c in 0..k {
            if counts[c] > 0 {
                centres[c] = sums[c].iter().map(|s| s / counts[c] as f64).collect();
            }
        }
    }
    let raw: Vec<usize> = points.iter().map(|p| nearest(p, &centres)).collect();
    let mut renumber = vec![usize::MAX; k];
    let mut next = 0;
    raw.iter()
        .map(|c| {
            if renumber[*c] == usize::MAX {
                renumber[*c] = next;
                next += 1;
            }
            renumber[*c]
        })
        .collect()
}

/// The fold (0..folds) of every row, groups kept whole: groups largest first
/// (ties by group number), each to the fold with the fewest rows so far (ties
/// by fold number). Groups are shuffled with `seed` before the sort so equal
/// sizes (plain k-fold: every group one row) spread at random.
pub fn folds_of_groups(
    groups: &[usize],
    folds: usize,
    grouping: Grouping,
    seed: u64,
) -> Result<Vec<usize>, GroupError> {
    let count = groups.iter().copied().max().map_or(0, |g| g + 1);
    let mut sizes = vec![0usize; count];
    for g in groups {
        sizes[*g] += 1;
    }
    let present = sizes.iter().filter(|s| **s > 0).count();
    if present < folds {
        return Err(GroupError::TooFewGroups {
            grouping,
            found: present,
            wanted: folds,
        });
    }
    let mut order: Vec<usize> = (0..count).filter(|g| sizes[*g] > 0).collect();
    let mut rng = StdRng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
    for i in (1..order.len()).rev() {
        let j = rng.random_range(0..=i);
        order.swap(i, j);
    }
    // Stable: equal sizes keep the shuffled order.
    order.sort_by_key(|g| std::cmp::Reverse(sizes[*g]));
    let mut fold_of_group = vec![0usize; count];
    let mut fold_rows = vec![0usize; folds];
    for g in order {
        let fold = (0..folds).min_by_key(|f| (fold_rows[*f], *f)).unwrap_or(0);
        fold_of_group[g] = fold;
        fold_rows[fold] += sizes[g];
    }
    Ok(groups.iter().map(|g| fold_of_group[*g]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::Wrench;

    fn row(q: [f64; 6], force_z: f64) -> ConfWrench {
        ConfWrench::new(
            crate::robot::joint_array(&q),
            Wrench {
                force_n: Vector3::new(0.0, 0.0, force_z),
                moment_nm: Vector3::zeros(),
            },
        )
    }

    /// Two far clusters of positions and joints, 20 rows each, interleaved.
    fn two_clusters() -> (Vec<ConfWrench>, Vec<Vector3<f64>>) {
        let mut rows = Vec::new();
        let mut points = Vec::new();
        for k in 0..40 {
            let side = (k % 2) as f64;
            let jitter = (k as f64 * 0.37).sin();
            rows.push(row(
                [
                    -60.0 + 120.0 * side + jitter,
                    10.0 * jitter,
                    20.0,
                    0.0,
                    30.0,
                    0.0,
                ],
                if side > 0.5 { 100.0 } else { 0.0 },
            ));
            points.push(Vector3::new(
                500.0 + 1000.0 * side + 10.0 * jitter,
                jitter,
                800.0,
            ));
        }
        (rows, points)
    }

    #[test]
    fn region_configuration_and_load_find_the_two_clusters() {
        let (rows, points) = two_clusters();
        let input = GroupInput {
            rows: &rows,
            positions_mm: &points,
            measured_at_us: None,
        };
        for grouping in [Grouping::Region, Grouping::Configuration, Grouping::Load] {
            let groups = group_rows(grouping, &input, 2, 7).unwrap();
            // Renumbered by first row: row 0's cluster is 0.
            for (k, g) in groups.iter().enumerate() {
                assert_eq!(*g, k % 2, "{grouping}: row {k}");
            }
        }
    }

    #[test]
    fn time_blocks_follow_the_timestamps_not_the_table_order() {
        let (rows, points) = two_clusters();
        let times: Vec<i64> = (0..40).map(|k| (39 - k) * 1_000_000).collect();
        let input = GroupInput {
            rows: &rows,
            positions_mm: &points,
            measured_at_us: Some(&times),
        };
        let groups = group_rows(Grouping::Time, &input, 4, 0).unwrap();
        // Latest rows first in the table: the first ten rows are the last block.
        assert!(groups[..10].iter().all(|g| *g == 3));
        assert!(groups[30..].iter().all(|g| *g == 0));
        let no_times = GroupInput {
            measured_at_us: None,
            ..input
        };
        assert_eq!(
            group_rows(Grouping::Time, &no_times, 4, 0),
            Err(GroupError::NoTimes)
        );
    }

    #[test]
    fn one_load_cannot_be_grouped_by_load() {
        let rows: Vec<ConfWrench> = (0..10).map(|k| row([k as f64; 6], 5.0)).collect();
        let points = vec![Vector3::zeros(); 10];
        let input = GroupInput {
            rows: &rows,
            positions_mm: &points,
            measured_at_us: None,
        };
        assert_eq!(
            group_rows(Grouping::Load, &input, 3, 0),
            Err(GroupError::OneLoad)
        );
    }

    #[test]
    fn folds_keep_groups_whole_balance_rows_and_repeat_with_the_seed() {
        let groups: Vec<usize> = (0..100).map(|k| (k * k) % 9).collect();
        let a = folds_of_groups(&groups, 3, Grouping::Region, 11).unwrap();
        assert_eq!(
            a,
            folds_of_groups(&groups, 3, Grouping::Region, 11).unwrap()
        );
        for g in 0..9 {
            let folds: std::collections::BTreeSet<usize> = groups
                .iter()
                .zip(&a)
                .filter(|(gg, _)| **gg == g)
                .map(|(_, f)| *f)
                .collect();
            assert!(folds.len() <= 1, "group {g} split over folds {folds:?}");
        }
        let random: Vec<usize> = (0..90).collect();
        let f = folds_of_groups(&random, 3, Grouping::Random, 5).unwrap();
        for fold in 0..3 {
            assert_eq!(f.iter().filter(|x| **x == fold).count(), 30);
        }
        assert_ne!(f, folds_of_groups(&random, 3, Grouping::Random, 6).unwrap());
        assert!(matches!(
            folds_of_groups(&[0, 0, 1, 1], 3, Grouping::Region, 0),
            Err(GroupError::TooFewGroups { found: 2, .. })
        ));
    }
}
