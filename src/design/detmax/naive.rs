//! The paper's exchange as written: every trial set's Jacobian gets a fresh SVD.
//! Kept to verify the fast engine and to measure what it saves; trials run in
//! parallel like the fast engine's, so the comparison is of the maths only.

use super::{Candidates, Criterion, Engine, naive_best_addition, naive_exchange};

pub(super) struct Naive<'a> {
    c: &'a Candidates,
    criterion: Criterion,
    /// In order of entry.
    members: Vec<usize>,
    in_set: Vec<bool>,
}

impl<'a> Naive<'a> {
    pub(super) fn new(c: &'a Candidates, start: Vec<usize>, criterion: Criterion) -> Naive<'a> {
        let mut in_set = vec![false; c.len()];
        start.iter().for_each(|&k| in_set[k] = true);
        Naive {
            c,
            criterion,
            members: start,
            in_set,
        }
    }

    /// The criterion of a set, by the SVD of its stacked Jacobian.
    fn evaluate(&self, set: &[usize], criterion: Criterion) -> f64 {
        set_value(self.c, set, criterion)
    }
}

/// `criterion` of `set` from a fresh SVD.
fn set_value(c: &Candidates, set: &[usize], criterion: Criterion) -> f64 {
    let sv = c.jacobian(set).singular_values_unordered();
    criterion.evaluate(sv.as_slice(), set.len())
}

impl Engine for Naive<'_> {
    fn best_addition(&self) -> Option<usize> {
        naive_best_addition(&self.in_set, &self.members, |set| {
            self.evaluate(set, self.criterion)
        })
    }

    fn exchange(&mut self, added: usize) -> usize {
        let (c, criterion) = (self.c, self.criterion);
        naive_exchange(&mut self.members, &mut self.in_set, added, |set| {
            set_value(c, set, criterion)
        })
    }

    fn members(&self) -> &[usize] {
        &self.members
    }

    fn o1(&self) -> f64 {
        self.evaluate(&self.members, Criterion::O1)
    }

    fn value(&self) -> f64 {
        self.evaluate(&self.members, self.criterion)
    }

    fn refactorisations(&self) -> usize {
        0
    }
}
