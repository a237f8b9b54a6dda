//! Reading a stage's output tables in a test: the frame, and a column's
//! values (a missing or mistyped column fails the test, naming it).

use std::path::Path;

use egcal::table::{self, schema};
use polars::prelude::DataFrame;

pub fn read(path: &Path) -> DataFrame {
    table::read_parquet(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

pub fn f64s(df: &DataFrame, column: &str) -> Vec<f64> {
    schema::f64_values(df, column, Path::new(column)).unwrap()
}

pub fn i64s(df: &DataFrame, column: &str) -> Vec<i64> {
    schema::i64_values(df, column, Path::new(column)).unwrap()
}

/// A utf8 column's values, null read as "".
pub fn strings(df: &DataFrame, column: &str) -> Vec<String> {
    schema::str_values(df, column, Path::new(column))
        .unwrap()
        .into_iter()
        .map(Option::unwrap_or_default)
        .collect()
}
