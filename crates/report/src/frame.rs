//! Result rows -> polars DataFrame -> results.parquet / results.csv.
//!
//! Columns are derived generically from the serde representation of `ResultRow`, so a field added to
//! the row (an `Option`, per row.rs) shows up as a column without touching this file.
use bvhlab_pipeline::atomic::write_atomic_file;
use bvhlab_pipeline::ResultRow;
use polars::prelude::*;
use serde::de::{Deserializer, IgnoredAny, MapAccess, Visitor};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;

/// Name of the map field that is flattened into `key_<stage>` string columns.
const KEYS_FIELD: &str = "keys";

/// Field names of `ResultRow` in declaration order. serde_json's `Map` is sorted (we must not turn on
/// `preserve_order` workspace-wide: other crates may hash JSON), so read the order off the JSON text,
/// which serde writes in declaration order.
pub fn field_order() -> Result<Vec<String>, String> {
    struct Keys;
    impl<'de> Visitor<'de> for Keys {
        type Value = Vec<String>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a JSON object")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Vec<String>, A::Error> {
            let mut keys = Vec::new();
            while let Some((k, _)) = map.next_entry::<String, IgnoredAny>()? {
                keys.push(k);
            }
            Ok(keys)
        }
    }
    let text = serde_json::to_string(&ResultRow::default()).map_err(|e| e.to_string())?;
    let mut de = serde_json::Deserializer::from_str(&text);
    de.deserialize_map(Keys).map_err(|e| e.to_string())
}

/// Builds the results table: one row per `ResultRow`, columns in `ResultRow` field order with `keys`
/// expanded in place to `key_<stage>` (stages sorted). Non-finite floats become null (serde_json
/// cannot represent them).
pub fn to_dataframe(rows: &[ResultRow]) -> Result<DataFrame, String> {
    let fields = field_order()?;
    let values: Vec<serde_json::Map<String, Value>> = rows
        .iter()
        .map(|r| match serde_json::to_value(r) {
            Ok(Value::Object(m)) => Ok(m),
            Ok(other) => Err(format!("result row serialized to {other}, expected an object")),
            Err(e) => Err(format!("cannot serialize result row: {e}")),
        })
        .collect::<Result<_, _>>()?;

    let mut columns: Vec<Column> = Vec::new();
    for field in &fields {
        let cells: Vec<&Value> =
            values.iter().map(|m| m.get(field).unwrap_or(&Value::Null)).collect();
        if field == KEYS_FIELD {
            let stages: BTreeSet<&String> = cells
                .iter()
                .filter_map(|v| v.as_object())
                .flat_map(|m| m.keys())
                .collect();
            for stage in stages {
                let col: Vec<Option<String>> = cells
                    .iter()
                    .map(|v| v.get(stage.as_str()).map(json_to_string))
                    .collect();
                columns.push(Column::new(format!("key_{stage}").into(), col));
            }
            continue;
        }
        columns.push(column_from_json(field, &cells));
    }
    DataFrame::new(rows.len(), columns).map_err(|e| format!("cannot build results table: {e}"))
}

/// Picks the narrowest polars type that holds every non-null cell: Boolean, Int64, Float64, else
/// String (nested values as JSON text). All-null columns (an Option field no row has set) are Float64,
/// since most optional fields are measurements.
fn column_from_json(name: &str, cells: &[&Value]) -> Column {
    let non_null = || cells.iter().filter(|v| !v.is_null());
    let all_bool = non_null().all(|v| v.is_boolean());
    let all_int = non_null().all(|v| v.is_i64());
    let all_num = non_null().all(|v| v.is_number());
    let any = non_null().next().is_some();
    let name: PlSmallStr = name.into();
    if any && all_bool {
        let c: Vec<Option<bool>> = cells.iter().map(|v| v.as_bool()).collect();
        Column::new(name, c)
    } else if any && all_int {
        let c: Vec<Option<i64>> = cells.iter().map(|v| v.as_i64()).collect();
        Column::new(name, c)
    } else if all_num {
        let c: Vec<Option<f64>> = cells.iter().map(|v| v.as_f64()).collect();
        Column::new(name, c)
    } else {
        let c: Vec<Option<String>> =
            cells.iter().map(|v| if v.is_null() { None } else { Some(json_to_string(v)) }).collect();
        Column::new(name, c)
    }
}

fn json_to_string(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

pub fn write_parquet(df: &mut DataFrame, path: &Path) -> Result<(), String> {
    write_atomic_file(path, |f| {
        ParquetWriter::new(f).finish(df).map(|_| ()).map_err(|e| e.to_string())
    })
}

/// Rows of an existing `results.parquet` (None: no readable report there).
pub fn parquet_rows(path: &Path) -> Option<usize> {
    let f = std::fs::File::open(path).ok()?;
    ParquetReader::new(f).finish().ok().map(|df| df.height())
}

pub fn write_csv(df: &mut DataFrame, path: &Path) -> Result<(), String> {
    write_atomic_file(path, |f| {
        CsvWriter::new(f).include_header(true).finish(df).map_err(|e| e.to_string())
    })
}
