//! The model ladder (issue #29): which of the models a crossvalidation
//! compared goes in service. The models are climbed from the simplest; a
//! richer rung replaces the one chosen so far only when its held-out errors,
//! row by row on the same grouped folds, are lower on average by at least a
//! minimum share of the simpler rung's mean, and both paired tests (t and
//! Wilcoxon) call the difference significant. The share is there because the
//! rows of a fold share one calibration, so row-level tests overstate
//! significance: a rung fitted to noise can come out a fraction of a percent
//! better "significantly" on a thousand rows. Nor is a rung chosen that is
//! worse than the one below it, or whose tail is: a 99.7th percentile of the
//! held-out errors above the simpler rung's by more than the same share. A
//! richer model that extrapolates badly in a few held-out configurations can
//! lower the mean while raising the errors a tolerance is judged on; it must
//! not trade one for the other.
//!
//! The climb may start above the simplest rung (`crossvalidate` starts at the
//! paper's elasto-geometric model, egcal's default): the rungs below are
//! listed with their figures but never chosen, so no rung worse than the
//! starting one goes in service because a simpler one failed the rule.

use std::collections::BTreeMap;

use crate::stats;

/// One rung's held-out errors: the model and (cw_id, error mm) per row.
#[derive(Debug, Clone, PartialEq)]
pub struct Rung {
    pub model: String,
    pub errors_mm: Vec<(i64, f64)>,
}

/// What the climb decided at one rung.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub model: String,
    /// Mean held-out error over the rows (mm).
    pub mean_mm: f64,
    /// The rung chosen so far that this one was compared with; `None` for the
    /// first rung.
    pub compared_with: Option<String>,
    /// Mean of this rung's error minus the other's, row by row (mm).
    pub mean_difference_mm: Option<f64>,
    pub paired_t_p: Option<f64>,
    pub wilcoxon_p: Option<f64>,
    /// Whether the climb moved to this rung (or started at it).
    pub accepted: bool,
    pub reason: String,
}

/// The decision: every rung's step, and the index of the chosen one.
#[derive(Debug, Clone, PartialEq)]
pub struct Climb {
    pub steps: Vec<Step>,
    pub chosen: usize,
}

/// What a richer rung must show to be chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rule {
    /// Both paired tests' p-values below this.
    pub alpha: f64,
    /// The mean error lower by at least this share of the simpler rung's.
    pub min_gain: f64,
}

/// Climbs `rungs`, given simplest first, by `rule`, from the rung at
/// `start`. `None` when there is no rung there.
pub fn climb(rungs: &[Rung], rule: Rule, start: usize) -> Option<Climb> {
    let Rule { alpha, min_gain } = rule;
    let first = rungs.get(start)?;
    let mean = |rung: &Rung| {
        rung.errors_mm.iter().map(|(_, e)| e).sum::<f64>() / rung.errors_mm.len().max(1) as f64
    };
    let step = |rung: &Rung, accepted: bool, reason: String| Step {
        model: rung.model.clone(),
        mean_mm: mean(rung),
        compared_with: None,
        mean_difference_mm: None,
        paired_t_p: None,
        wilcoxon_p: None,
        accepted,
        reason,
    };
    let mut steps: Vec<Step> = rungs[..start]
        .iter()
        .map(|rung| {
            step(
                rung,
                false,
                format!(
                    "simpler than {}, where the ladder starts: not a candidate",
                    first.model
                ),
            )
        })
        .collect();
    steps.push(step(
        first,
        true,
        if start == 0 {
            "the simplest model compared".into()
        } else {
            "where the ladder starts".into()
        },
    ));
    let mut chosen = start;
    for (index, rung) in rungs.iter().enumerate().skip(start + 1) {
        let current = &rungs[chosen];
        let (ours, theirs) = paired(rung, current);
        let differences: Vec<f64> = ours.iter().zip(&theirs).map(|(a, b)| a - b).collect();
        let mean_difference = (!differences.is_empty())
            .then(|| differences.iter().sum::<f64>() / differences.len() as f64);
        // Identical errors (a term the rows cannot see) have no variance:
        // nothing to tell apart.
        let t = stats::paired_t(&ours, &theirs).ok().map(|t| t.p_value);
        let w = stats::wilcoxon_signed_rank(&ours, &theirs)
            .ok()
            .map(|w| w.p_value);
        let significant = |p: Option<f64>| p.is_some_and(|p| p < alpha);
        let (tail, current_tail) = (tail_mm(&ours), tail_mm(&theirs));
        let (accepted, reason) = match mean_difference {
            None => (
                false,
                format!("no held-out row in common with {}", current.model),
            ),
            Some(d) if d >= 0.0 => (
                false,
                format!(
                    "held-out mean {:.4} mm is not below {:.4} mm of {}",
                    mean(rung),
                    mean(current),
                    current.model
                ),
            ),
            Some(d) if -d < min_gain * mean(current) => (
                false,
                format!(
                    "held-out mean {:.4} mm, {:.4} mm below {}: less than the {}% gain a richer model must show",
                    mean(rung),
                    -d,
                    current.model,
                    min_gain * 100.0
                ),
            ),
            Some(_) if tail > current_tail * (1.0 + min_gain) => (
                false,
                format!(
                    "held-out mean {:.4} mm is below {}'s {:.4} mm, but the 99.7th percentile {tail:.4} mm is {:.0}% above its {current_tail:.4} mm: a richer model must not trade the tail for the mean",
                    mean(rung),
                    current.model,
                    mean(current),
                    (tail / current_tail - 1.0) * 100.0
                ),
            ),
            Some(d) if significant(t) && significant(w) => (
                true,
                format!(
                    "held-out mean {:.4} mm, {:.4} mm below {} (paired t p = {}, Wilcoxon p = {})",
                    mean(rung),
                    -d,
                    current.model,
                    p_text(t),
                    p_text(w)
                ),
            ),
            Some(d) => (
                false,
                format!(
                    "held-out mean {:.4} mm below {} by {:.4} mm, not significant at {alpha} (paired t p = {}, Wilcoxon p = {})",
                    mean(rung),
                    current.model,
                    -d,
                    p_text(t),
                    p_text(w)
                ),
            ),
        };
        steps.push(Step {
            model: rung.model.clone(),
            mean_mm: mean(rung),
            compared_with: Some(current.model.clone()),
            mean_difference_mm: mean_difference,
            paired_t_p: t,
            wilcoxon_p: w,
            accepted,
            reason,
        });
        if accepted {
            chosen = index;
        }
    }
    Some(Climb { steps, chosen })
}

/// The 99.7th percentile of held-out errors (mm); 0 for none.
fn tail_mm(errors_mm: &[f64]) -> f64 {
    stats::percentile(errors_mm, 0.997).unwrap_or(0.0)
}

/// The errors of the rows both rungs predicted, in cw_id order.
fn paired(a: &Rung, b: &Rung) -> (Vec<f64>, Vec<f64>) {
    let others: BTreeMap<i64, f64> = b.errors_mm.iter().copied().collect();
    a.errors_mm
        .iter()
        .filter_map(|(id, e)| others.get(id).map(|other| (*e, *other)))
        .unzip()
}

/// A p-value for the reason text; one below the smallest normal double (the
/// t distribution's tail underflows there) is written as a bound, not `0`.
fn p_text(p: Option<f64>) -> String {
    match p {
        None => "undefined".into(),
        Some(p) if p < f64::MIN_POSITIVE => format!("< {:.0e}", f64::MIN_POSITIVE),
        Some(p) => format!("{p:.2e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULE: Rule = Rule {
        alpha: 0.05,
        min_gain: 0.05,
    };

    fn rung(model: &str, errors: impl Fn(i64) -> f64) -> Rung {
        Rung {
            model: model.into(),
            errors_mm: (0..200).map(|id| (id, errors(id))).collect(),
        }
    }

    /// A wobble around a level, the same rows for every rung.
    fn wobble(id: i64) -> f64 {
        ((id as f64) * 0.7).sin() * 0.01
    }

    #[test]
    fn a_significantly_better_rung_is_chosen_and_noise_is_not() {
        let rungs = [
            rung("elastogeometric", |id| 0.10 + wobble(id)),
            // Clearly better on every row.
            rung("eg_backlash", |id| 0.04 + wobble(id) * 0.5),
            // Slightly worse than the backlash rung: fits noise.
            rung("eg_harmonic", |id| {
                0.0402 + wobble(id) * 0.5 + wobble(id + 3) * 0.001
            }),
        ];
        let climb = climb(&rungs, RULE, 0).unwrap();
        assert_eq!(climb.chosen, 1);
        assert!(climb.steps[1].accepted && !climb.steps[2].accepted);
        assert_eq!(climb.steps[2].compared_with.as_deref(), Some("eg_backlash"));
        assert!(
            climb.steps[2].reason.contains("not below"),
            "{}",
            climb.steps[2].reason
        );
    }

    #[test]
    fn a_lower_mean_that_is_not_significant_is_not_chosen() {
        // Differences alternate in sign around a small mean improvement; a
        // few large errors in both keep the tails alike.
        let base = |id: i64| 0.10 + wobble(id) + if id < 3 { 5.0 } else { 0.0 };
        let rungs = [
            rung("elastogeometric", base),
            rung("eg_backlash", |id| {
                base(id) - 0.012 + if id % 2 == 0 { 0.2 } else { -0.2 }
            }),
        ];
        let climb = climb(&rungs, RULE, 0).unwrap();
        assert_eq!(climb.chosen, 0);
        assert!(climb.steps[1].reason.contains("not significant"));
    }

    #[test]
    fn a_significant_but_small_gain_is_not_chosen() {
        let rungs = [
            rung("elastogeometric", |id| 0.10 + wobble(id)),
            rung("eg_backlash", |id| {
                0.098 + wobble(id) + 1e-4 * (id % 3) as f64
            }),
        ];
        let climb = climb(&rungs, RULE, 0).unwrap();
        assert_eq!(climb.chosen, 0);
        assert!(climb.steps[1].paired_t_p.unwrap() < 1e-6);
        assert!(
            climb.steps[1].reason.contains("5% gain"),
            "{}",
            climb.steps[1].reason
        );
    }

    #[test]
    fn identical_errors_keep_the_simpler_rung() {
        let rungs = [
            rung("elastogeometric", |id| 0.1 + wobble(id)),
            rung("eg_backlash", |id| 0.1 + wobble(id)),
        ];
        let climb = climb(&rungs, RULE, 0).unwrap();
        assert_eq!(climb.chosen, 0);
        assert_eq!(climb.steps[1].paired_t_p, None);
        assert!(super::climb(&[], RULE, 0).is_none());
    }

    /// The UR10 case of eg_residual on configuration folds: the mean 13 %
    /// lower, the few worst rows (a harmonic extrapolated) far higher.
    #[test]
    fn a_lower_mean_with_a_worse_tail_is_not_chosen() {
        let rungs = [
            rung("elastogeometric", |id| 0.47 + wobble(id)),
            rung("eg_residual", |id| {
                0.41 + wobble(id) + if id % 50 == 0 { 1.0 } else { 0.0 }
            }),
        ];
        let climb = climb(&rungs, RULE, 0).unwrap();
        assert_eq!(climb.chosen, 0);
        assert!(
            climb.steps[1].reason.contains("trade the tail"),
            "{}",
            climb.steps[1].reason
        );
    }

    /// The UR10 case: the geometric model is 2 % worse held out than the
    /// elasto-geometric one, below the minimum gain. Climbed from the
    /// simplest, the geometric model would stay in service; started at the
    /// elasto-geometric model it is listed but never chosen.
    #[test]
    fn rungs_below_the_start_are_listed_but_never_chosen() {
        let rungs = [
            rung("registered", |id| 1.0 + wobble(id)),
            rung("kinematic", |id| 0.4775 + wobble(id)),
            rung("elastogeometric", |id| {
                0.4682 + wobble(id) + 1e-4 * (id % 3) as f64
            }),
            rung("eg_harmonic", |id| 0.50 + wobble(id)),
        ];
        assert_eq!(climb(&rungs, RULE, 0).unwrap().chosen, 1);
        let climb = climb(&rungs, RULE, 2).unwrap();
        assert_eq!(climb.steps.len(), 4);
        assert_eq!(climb.chosen, 2);
        assert!(!climb.steps[0].accepted && !climb.steps[1].accepted);
        assert!(climb.steps[1].reason.contains("where the ladder starts"));
        assert_eq!(
            climb.steps[3].compared_with.as_deref(),
            Some("elastogeometric")
        );
        assert!(!climb.steps[3].accepted);
    }
}
