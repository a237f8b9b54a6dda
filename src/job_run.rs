//! Running a loaded plan to its end: the runner's stages, then the decisions of
//! its gate stages as the exit code. `egcal run` and each robot-night of a fleet
//! (`fleet/`) run a job through here.

use std::fmt::Write as _;
use std::path::Path;

use crate::exit_code::{self, Finished};
use crate::gate::Decision;
use crate::job::Plan;
use crate::runner::{self, RunError, RunOptions, progress::Reporter};
use crate::table::{self, TableError};

/// Runs `plan`; the exit code is the most urgent of its gate stages' decisions.
pub fn run_plan(mut plan: Plan, options: &RunOptions, quiet: bool) -> Result<Finished, RunError> {
    if let Some(day) = options.run_date {
        plan.run_date = day;
    }
    let reporter = Reporter::new(quiet);
    let outcomes = runner::run(&plan, options, &reporter)?;
    let ran = outcomes
        .iter()
        .filter(|(_, o)| matches!(o, runner::Outcome::Ran { .. }))
        .count();
    let mut message = format!(
        "{}: {} stage(s), {ran} ran, {} cached; outputs in {}",
        plan.name,
        outcomes.len(),
        outcomes.len() - ran,
        plan.output_dir.display()
    );
    let mut decisions = Vec::new();
    for (id, _) in &outcomes {
        let is_gate = plan
            .stage_index(id)
            .is_some_and(|i| plan.stages[i].kind.info().kind == "gate");
        if is_gate {
            let decision =
                gate_decision(&plan.output_dir.join(id)).map_err(|e| RunError::Table {
                    stage: id.clone(),
                    source: Box::new(e),
                })?;
            write!(message, "\n{id}: {}", decision.as_str()).expect("write to string");
            decisions.push(decision);
        }
    }
    Ok(Finished {
        message,
        code: gate_code(&decisions),
    })
}

/// The exit code of gate decisions, the most urgent first: refused, published, kept.
pub fn gate_code(decisions: &[Decision]) -> u8 {
    if decisions.contains(&Decision::Refused) {
        exit_code::GATE_REFUSED
    } else if decisions.contains(&Decision::Published) {
        exit_code::GATE_PUBLISHED
    } else {
        exit_code::OK
    }
}

/// The decision a gate stage wrote into `dir/decision.parquet`.
pub fn gate_decision(dir: &Path) -> Result<Decision, TableError> {
    let path = dir.join("decision.parquet");
    let df = table::read_checked(&path, &table::schema::gate_decision())?;
    let values = table::schema::str_values(&df, "decision", &path)?;
    let text = values.first().cloned().flatten().unwrap_or_default();
    Decision::parse(&text).ok_or_else(|| TableError::BadValue {
        file: path,
        column: "decision".into(),
        row: 0,
        message: format!("expected kept, published or refused, found `{text}`"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_most_urgent_gate_decision_sets_the_exit_code() {
        use Decision::*;
        assert_eq!(gate_code(&[]), exit_code::OK);
        assert_eq!(gate_code(&[Kept, Kept]), exit_code::OK);
        assert_eq!(gate_code(&[Kept, Published]), exit_code::GATE_PUBLISHED);
        assert_eq!(
            gate_code(&[Published, Refused, Kept]),
            exit_code::GATE_REFUSED
        );
    }
}
