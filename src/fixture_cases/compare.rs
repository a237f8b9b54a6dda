//! Expected table against output table: the expected columns, row by row.
//! Floats agree within `tolerance × max(1, |expected|)` (NaN only with NaN);
//! everything else exactly, timestamps as their physical µs whatever their
//! time-zone tag. A difference names the table, column, row (with the row's
//! leading key columns, so `row 3` can be found), expected and actual values.

use polars::prelude::*;

/// Cell differences listed before "… and N more".
const LISTED: usize = 5;

/// Differences of `actual` from `expected`, as sentences; empty when they agree.
pub fn differences(
    table: &str,
    expected: &DataFrame,
    actual: &DataFrame,
    tolerance: f64,
) -> Vec<String> {
    if expected.height() != actual.height() {
        return vec![format!(
            "table `{table}`: {} rows, expected {}",
            actual.height(),
            expected.height()
        )];
    }
    let labels = RowLabels::of(expected);
    let mut found = Vec::new();
    let mut more = 0usize;
    for column in expected.columns() {
        let name = column.name().as_str();
        let Ok(other) = actual.column(name) else {
            found.push(format!("table `{table}`: no column `{name}`"));
            continue;
        };
        let cells = if column.dtype().is_float() {
            float_differences(column, other, tolerance)
        } else {
            exact_differences(column, other)
        };
        let cells = match cells {
            Ok(cells) => cells,
            Err(message) => {
                found.push(format!("table `{table}`, column `{name}`: {message}"));
                continue;
            }
        };
        for (row, want, got, note) in cells {
            if found.len() >= LISTED {
                more += 1;
                continue;
            }
            found.push(format!(
                "table `{table}`, column `{name}`, row {row}{}: expected {want}, actual {got}{note}",
                labels.describe(row)
            ));
        }
    }
    if more > 0 {
        found.push(format!("… and {more} more differing cells"));
    }
    found
}

/// (row, expected, actual, note) of each differing cell.
type Cells = Vec<(usize, String, String, String)>;

fn float_differences(want: &Column, got: &Column, tolerance: f64) -> Result<Cells, String> {
    if !got.dtype().is_float() {
        return Err(format!("type {}, expected {}", got.dtype(), want.dtype()));
    }
    let a = want.cast(&DataType::Float64).map_err(|e| e.to_string())?;
    let b = got.cast(&DataType::Float64).map_err(|e| e.to_string())?;
    let (a, b) = (
        a.f64().map_err(|e| e.to_string())?,
        b.f64().map_err(|e| e.to_string())?,
    );
    let mut cells = Vec::new();
    for (row, (x, y)) in a.iter().zip(b.iter()).enumerate() {
        let agree = match (x, y) {
            // Infinities and NaN agree only with themselves: a tolerance scaled
            // by an infinite expected value would accept anything.
            (Some(x), Some(y)) if !(x.is_finite() && y.is_finite()) => {
                x == y || (x.is_nan() && y.is_nan())
            }
            (Some(x), Some(y)) => (x - y).abs() <= tolerance * x.abs().max(1.0),
            (None, None) => true,
            _ => false,
        };
        if !agree {
            let note = match (x, y) {
                (Some(x), Some(y)) if x.is_finite() && y.is_finite() => format!(
                    " (difference {:.3e}, allowed {:.3e})",
                    (x - y).abs(),
                    tolerance * x.abs().max(1.0)
                ),
                _ => String::new(),
            };
            cells.push((row, show_float(x), show_float(y), note));
        }
    }
    Ok(cells)
}

fn show_float(value: Option<f64>) -> String {
    value.map_or("null".to_string(), |v| format!("{v:?}"))
}

fn exact_differences(want: &Column, got: &Column) -> Result<Cells, String> {
    if !same_type(want.dtype(), got.dtype()) {
        return Err(format!("type {}, expected {}", got.dtype(), want.dtype()));
    }
    let a = want.to_physical_repr();
    let b = got.to_physical_repr();
    let (a, b) = (a.as_materialized_series(), b.as_materialized_series());
    let mut cells = Vec::new();
    for row in 0..a.len() {
        let (x, y) = (
            a.get(row).map_err(|e| e.to_string())?,
            b.get(row).map_err(|e| e.to_string())?,
        );
        if x != y {
            cells.push((row, show(&x), show(&y), String::new()));
        }
    }
    Ok(cells)
}

/// Equal types, but a timestamp's time-zone tag aside (the values are UTC µs
/// either way).
fn same_type(a: &DataType, b: &DataType) -> bool {
    match (a, b) {
        (DataType::Datetime(unit_a, _), DataType::Datetime(unit_b, _)) => unit_a == unit_b,
        _ => a == b,
    }
}

fn show(value: &AnyValue) -> String {
    match value {
        AnyValue::String(s) => format!("{s:?}"),
        AnyValue::StringOwned(s) => format!("{:?}", s.as_str()),
        other => other.to_string(),
    }
}

/// The first two columns of the expected table that are not floats (model and
/// parameter name, cw_id, target id): what a person searches for to find a row.
struct RowLabels<'a> {
    columns: Vec<&'a Column>,
}

impl<'a> RowLabels<'a> {
    fn of(table: &'a DataFrame) -> Self {
        RowLabels {
            columns: table
                .columns()
                .iter()
                .filter(|c| !c.dtype().is_float() && !c.dtype().is_nested())
                .take(2)
                .collect(),
        }
    }

    fn describe(&self, row: usize) -> String {
        let parts: Vec<String> = self
            .columns
            .iter()
            .filter_map(|c| {
                let value = c.get(row).ok()?;
                Some(format!("{} = {}", c.name(), show(&value)))
            })
            .collect();
        if parts.is_empty() {
            String::new()
        } else {
            format!(" ({})", parts.join(", "))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parameters(values: &[f64]) -> DataFrame {
        df!(
            "model" => vec!["kinematic"; values.len()],
            "name" => (0..values.len()).map(|i| format!("p{i}")).collect::<Vec<_>>(),
            "value" => values.to_vec(),
        )
        .unwrap()
    }

    #[test]
    fn equal_tables_within_the_tolerance_agree() {
        let want = parameters(&[1.0, 1000.0, f64::NAN]);
        let got = parameters(&[1.0 + 5e-7, 1000.0 + 4e-4, f64::NAN]);
        assert!(differences("parameters", &want, &got, 1e-6).is_empty());
    }

    #[test]
    fn infinities_agree_only_with_themselves() {
        for (want, got) in [
            (f64::INFINITY, 1.0),
            (f64::INFINITY, f64::NEG_INFINITY),
            (1.0, f64::INFINITY),
            (1.0, f64::NAN),
        ] {
            let found = differences("t", &parameters(&[want]), &parameters(&[got]), 1e-6);
            assert_eq!(found.len(), 1, "{want} against {got}");
        }
        let inf = parameters(&[f64::INFINITY]);
        assert!(differences("t", &inf, &inf, 1e-6).is_empty());
    }

    #[test]
    fn a_timestamp_is_not_an_integer() {
        let want = df!("t" => [1i64]).unwrap();
        let got = want
            .clone()
            .lazy()
            .with_column(col("t").cast(DataType::Datetime(TimeUnit::Microseconds, None)))
            .collect()
            .unwrap();
        assert!(differences("t", &want, &got, 0.0)[0].contains("type datetime"));
    }

    #[test]
    fn a_difference_names_table_column_row_and_both_values() {
        let want = parameters(&[1.0, 2.0]);
        let got = parameters(&[1.0, 2.5]);
        let found = differences("parameters", &want, &got, 1e-6);
        assert_eq!(
            found,
            vec![
                "table `parameters`, column `value`, row 1 (model = \"kinematic\", name = \"p1\"): \
                 expected 2.0, actual 2.5 (difference 5.000e-1, allowed 2.000e-6)"
            ]
        );
    }

    #[test]
    fn strings_rows_columns_and_types_are_checked() {
        let want = parameters(&[1.0]);
        let mut got = parameters(&[1.0]);
        got.rename("name", "label".into()).unwrap();
        assert_eq!(
            differences("t", &want, &got, 0.0),
            vec!["table `t`: no column `name`"]
        );
        assert!(
            differences("t", &want, &parameters(&[1.0, 2.0]), 0.0)[0]
                .contains("2 rows, expected 1")
        );
        let ints = df!("model" => ["kinematic"], "name" => ["p0"], "value" => [1i64]).unwrap();
        assert!(differences("t", &want, &ints, 0.0)[0].contains("type i64, expected f64"));
        let renamed = df!("model" => ["registered"], "name" => ["p0"], "value" => [1.0]).unwrap();
        assert!(differences("t", &want, &renamed, 0.0)[0]
            .contains("column `model`, row 0 (model = \"kinematic\", name = \"p0\"): expected \"kinematic\", actual \"registered\""));
    }

    #[test]
    fn many_differences_are_counted_not_listed() {
        let want = parameters(&[0.0; 8]);
        let got = parameters(&[1.0; 8]);
        let found = differences("t", &want, &got, 0.0);
        assert_eq!(found.len(), LISTED + 1);
        assert_eq!(found[LISTED], "… and 3 more differing cells");
    }
}
