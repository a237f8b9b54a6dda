//! The paper's exchange as written: every trial set's Jacobian gets a fresh SVD.
//! Kept to verify the fast engine and to measure what it saves; trials run in
//! parallel like the fast engine's, so the comparison is of the maths only.

use rayon::prelude::*;

use super::{Candidates, Criterion, Engine, best_of, removal_choice};

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
        let sv = self.c.jacobian(set).singular_values_unordered();
        criterion.evaluate(sv.as_slice(), set.len())
    }
}

impl Engine for Naive<'_> {
    fn best_addition(&self) -> Option<usize> {
        let scores: Vec<(usize, f64)> = (0..self.c.len())
            .into_par_iter()
            .filter(|&k| !self.in_set[k])
            .map(|k| {
                let trial = [self.members.as_slice(), &[k]].concat();
                (k, self.evaluate(&trial, self.criterion))
            })
            .collect();
        best_of(scores.into_iter())
    }

    fn exchange(&mut self, added: usize) -> usize {
        self.members.push(added);
        let scores: Vec<(usize, f64)> = (0..self.members.len())
            .into_par_iter()
            .map(|position| {
                let mut trial = self.members.clone();
                let k = trial.remove(position);
                (k, self.evaluate(&trial, self.criterion))
            })
            .collect();
        let removed = removal_choice(&scores, added);
        self.members.retain(|&k| k != removed);
        self.in_set[added] = true;
        self.in_set[removed] = false;
        removed
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
