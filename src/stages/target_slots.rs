//! The targets (SMRs) of a table of rows and each row's slot among them, as
//! `identify` numbers them: the distinct `target_id`s, sorted. The design
//! stages (`identifiability`, `select`) number candidates the same way, so
//! that a campaign measuring the arm's SMR and a positioner's nests is
//! analysed with the tool translations the fit will use (spec §7).

use super::{InputTable, StageError};
use crate::robot::params::MAX_TARGETS;
use crate::robot::{ConfWrench, ParamId, RobotSpec};
use crate::table::schema::str_values;

/// The targets of a table's rows and the slot of each row.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TargetSlots {
    /// The distinct target ids, sorted (an absent id reads as ""); empty for
    /// a table without `target_id`.
    pub ids: Vec<String>,
    /// Each row's index into `ids` (0 without the column).
    pub slot_of_row: Vec<usize>,
}

impl TargetSlots {
    /// Slots of rows with these ids; `None`: the table has no `target_id`.
    pub fn of_ids(row_ids: Option<&[Option<String>]>, rows: usize) -> TargetSlots {
        let Some(row_ids) = row_ids else {
            return TargetSlots {
                ids: Vec::new(),
                slot_of_row: vec![0; rows],
            };
        };
        let id_of = |id: &Option<String>| id.clone().unwrap_or_default();
        let ids: Vec<String> = row_ids
            .iter()
            .map(id_of)
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect();
        let slot_of_row = row_ids
            .iter()
            .map(|id| ids.binary_search(&id_of(id)).unwrap_or(0))
            .collect();
        TargetSlots { ids, slot_of_row }
    }

    /// How many tool translations the rows need (at least one).
    pub fn count(&self) -> usize {
        self.ids.len().max(1)
    }

    /// The slot of the arm's SMR: the first target that is not one of the
    /// robot file's positioner nests (0 when every target is a nest, or
    /// without a positioner). Rows the arm would run (the work's) use it.
    pub fn arm_slot(&self, spec: &RobotSpec) -> usize {
        let is_nest = |id: &String| {
            spec.positioner
                .as_ref()
                .is_some_and(|p| p.nests.contains(id))
        };
        self.ids.iter().position(|id| !is_nest(id)).unwrap_or(0)
    }
}

/// The targets of a table of candidate rows, each row aimed at its slot: a
/// table with more targets than can be fitted jointly is refused, naming them.
pub fn aim_candidates(
    input: &InputTable,
    rows: &mut [ConfWrench],
) -> Result<TargetSlots, StageError> {
    let ids = match input.df.column("target_id") {
        Ok(_) => Some(str_values(&input.df, "target_id", &input.path)?),
        Err(_) => None,
    };
    let slots = TargetSlots::of_ids(ids.as_deref(), rows.len());
    if slots.ids.len() > MAX_TARGETS {
        return Err(StageError::Invalid(format!(
            "{}: {} targets ({}); at most {MAX_TARGETS} can be fitted jointly",
            input.path.display(),
            slots.ids.len(),
            slots.ids.join(", ")
        )));
    }
    for (row, slot) in rows.iter_mut().zip(&slots.slot_of_row) {
        row.target = *slot;
    }
    Ok(slots)
}

/// Every parameter of the robot file's cell with `targets` tool
/// translations: the 42 (and each further target's translation), the
/// track's terms, the positioner's.
pub fn cell_parameters(spec: &RobotSpec, targets: usize) -> Vec<ParamId> {
    let joints = spec.joints.len();
    let one_target = ParamId::all_with_targets(joints, 1).count();
    ParamId::all_with_targets(joints, targets)
        .chain(ParamId::of_robot(spec).skip(one_target))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_take_the_slot_of_their_id_among_the_sorted_ids() {
        let ids: Vec<Option<String>> = ["table_b", "arm", "table_a", "arm"]
            .iter()
            .map(|s| Some(s.to_string()))
            .collect();
        let slots = TargetSlots::of_ids(Some(&ids), ids.len());
        assert_eq!(slots.ids, ["arm", "table_a", "table_b"]);
        assert_eq!(slots.slot_of_row, [2, 0, 1, 0]);
        assert_eq!(slots.count(), 3);
        let none = TargetSlots::of_ids(None, 2);
        assert_eq!(none.slot_of_row, [0, 0]);
        assert_eq!(none.count(), 1);
    }

    #[test]
    fn the_arm_s_slot_is_the_first_target_that_is_not_a_nest() {
        let robot = crate::robot::test_support::irb1600_with_positioner();
        let slots = |ids: &[&str]| {
            let ids: Vec<Option<String>> = ids.iter().map(|s| Some(s.to_string())).collect();
            TargetSlots::of_ids(Some(&ids), ids.len())
        };
        // Sorted: table_a, table_b, tool.
        assert_eq!(
            slots(&["tool", "table_a", "table_b"]).arm_slot(robot.spec()),
            2
        );
        assert_eq!(slots(&["arm", "table_c"]).arm_slot(robot.spec()), 0);
        assert_eq!(slots(&[]).arm_slot(robot.spec()), 0);
        let plain = crate::robot::test_support::irb1600();
        assert_eq!(slots(&["table_a", "tool"]).arm_slot(plain.spec()), 0);
    }

    #[test]
    fn the_cell_s_parameters_add_each_further_target_s_translation() {
        let robot = crate::robot::test_support::irb1600_with_positioner();
        let spec = robot.spec();
        let one: Vec<ParamId> = ParamId::of_robot(spec).collect();
        assert_eq!(cell_parameters(spec, 1), one);
        let four = cell_parameters(spec, 4);
        assert_eq!(four.len(), one.len() + 9);
        assert!(four.contains(&ParamId::target_translation(3, 2)));
        assert!(one.iter().all(|p| four.contains(p)));
    }
}
