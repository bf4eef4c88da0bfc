//! Result rows -> polars DataFrame -> results.parquet / results.csv; the summary's fronts and bests;
//! the papers' tables (../shared/reference/*.tsv) read and joined with ours for the reference comparison.
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

/// Per-group Pareto fronts on a DataFrame: for every value of `group` (in order of first
/// appearance), the rows that no other row of the group dominates when minimizing both `x` and `y`,
/// sorted by increasing x (ties: y, then `id`). Same definition as `plots::pareto::pareto_front`:
/// identical points are all on the front; rows with a null, NaN or infinite coordinate are never on
/// it and never dominate.
///
/// Polars operations: filter the finite rows, group by `group`, and per group sort by (x, y, id),
/// take the cumulative minimum of y, and keep a row when its y is that minimum (nothing at x <= its x
/// is lower) and strictly below the minimum over all smaller x (the cumulative minimum just before
/// the row's run of equal x, carried forward over the run).
pub fn fronts(df: &DataFrame, group: &str, id: &str, x: &str, y: &str) -> PolarsResult<DataFrame> {
    let finite = df.column(x)?.is_finite()? & df.column(y)?.is_finite()?;
    let finite = finite.fill_null_with_values(false)?;
    let pts = df.filter(&finite)?;
    if pts.height() == 0 {
        return Ok(pts);
    }
    let (x, y, id) = (x.to_string(), y.to_string(), id.to_string());
    pts.group_by_stable([group])?.apply(move |g| {
        let g = g.sort([x.as_str(), y.as_str(), id.as_str()], SortMultipleOptions::default().with_maintain_order(true))?;
        let ys = g.column(&y)?.as_materialized_series().cast(&DataType::Float64)?;
        let xs = g.column(&x)?.as_materialized_series().cast(&DataType::Float64)?;
        let (ys, xs) = (ys.f64()?, xs.f64()?);
        let lowest = cum_min(&ys.clone().into_series(), false)?;
        let lowest = lowest.f64()?;
        // Lowest y strictly before each row, then the value at the first row of each run of equal x.
        let before = lowest.shift_and_fill(1, Some(f64::INFINITY));
        let run_start = xs.not_equal_missing(&xs.shift(1));
        let before_run = before.set(&!&run_start, None)?.into_series().fill_null(FillNullStrategy::Forward(None))?;
        let on_front = ys.equal(lowest) & ys.lt(before_run.f64()?);
        g.filter(&on_front)
    })
}

/// `fronts` as (group value, ids in front order) pairs; `id` must be a UInt32 column.
pub fn front_ids(df: &DataFrame, group: &str, id: &str, x: &str, y: &str) -> PolarsResult<Vec<(String, Vec<u32>)>> {
    let f = fronts(df, group, id, x, y)?;
    let mut out: Vec<(String, Vec<u32>)> = Vec::new();
    if f.height() == 0 {
        return Ok(out);
    }
    let groups = f.column(group)?.as_materialized_series().cast(&DataType::String)?;
    let ids = f.column(id)?.as_materialized_series().cast(&DataType::UInt32)?;
    for (g, i) in groups.str()?.iter().zip(ids.u32()?.iter()) {
        let (g, i) = (g.unwrap_or_default(), i.unwrap_or_default());
        match out.last_mut() {
            Some((last, v)) if last == g => v.push(i),
            _ => out.push((g.to_string(), vec![i])),
        }
    }
    Ok(out)
}

/// Per-group best row: for every value of `group` (in order of first appearance), the `id` and
/// value of the row with the lowest (`max`: highest) finite `v`, the first such row on a tie.
/// Polars operations: filter the finite rows, group by `group`, per group a stable sort by `v`
/// and the first row.
pub fn group_best(df: &DataFrame, group: &str, id: &str, v: &str, max: bool) -> PolarsResult<Vec<(String, u32, f64)>> {
    let finite = df.column(v)?.is_finite()?.fill_null_with_values(false)?;
    let vals = df.filter(&finite)?;
    if vals.height() == 0 {
        return Ok(Vec::new());
    }
    let col = v.to_string();
    let opts = SortMultipleOptions::default().with_order_descending(max).with_maintain_order(true);
    let best = vals.group_by_stable([group])?.apply(move |g| Ok(g.sort([col.as_str()], opts.clone())?.head(Some(1))))?;
    let groups = best.column(group)?.as_materialized_series().cast(&DataType::String)?;
    let ids = best.column(id)?.as_materialized_series().cast(&DataType::UInt32)?;
    let vs = best.column(v)?.as_materialized_series().cast(&DataType::Float64)?;
    Ok(groups
        .str()?
        .iter()
        .zip(ids.u32()?.iter())
        .zip(vs.f64()?.iter())
        .map(|((g, i), x)| (g.unwrap_or_default().to_string(), i.unwrap_or_default(), x.unwrap_or(f64::NAN)))
        .collect())
}

/// A tab-separated table of ../shared/reference read with polars' csv reader, every column as
/// text (the callers cast; a cell that does not parse becomes null).
pub fn read_tsv(path: &Path) -> Result<DataFrame, String> {
    CsvReadOptions::default()
        .with_has_header(true)
        .with_infer_schema_length(Some(0))
        .map_parse_options(|o| o.with_separator(b'\t'))
        .try_into_reader_with_file_path(Some(path.to_path_buf()))
        .and_then(|r| r.finish())
        .map_err(|e| format!("{}: {e}", path.display()))
}

/// The long form of a paper table: one row per (Scene, column) cell, `paper` its value.
pub fn empty_paper_table() -> PolarsResult<DataFrame> {
    df!("Scene" => Vec::<String>::new(), "column" => Vec::<String>::new(), "paper" => Vec::<f64>::new())
}

/// A paper table (header `Scene<TAB>COLUMN...`, one row per scene; `read_tsv`) in long form
/// (`empty_paper_table`): the cells that parse as numbers.
pub fn read_paper_table(path: &Path) -> Result<DataFrame, String> {
    let wide = read_tsv(path)?;
    let err = |e: PolarsError| format!("{}: {e}", path.display());
    let Some((scene, values)) = wide.columns().split_first() else {
        return Err(format!("{}: empty table", path.display()));
    };
    let scene = scene.clone().with_name("Scene".into());
    let mut long = empty_paper_table().map_err(err)?;
    for v in values {
        let column = Column::new("column".into(), vec![v.name().as_str(); wide.height()]);
        let paper = v.cast(&DataType::Float64).map_err(err)?.with_name("paper".into());
        let part = DataFrame::new(wide.height(), vec![scene.clone(), column, paper]).map_err(err)?;
        long.vstack_mut(&part).map_err(err)?;
    }
    let parsed = long.column("paper").map_err(err)?.is_not_null();
    long.filter(&parsed).map_err(err)
}

/// The values of a long paper table at `keys` (scene, column), in key order (None: no such cell):
/// a left join on (Scene, column); a table holding a cell twice is an error.
pub fn lookup(table: &DataFrame, keys: &[(String, String)]) -> PolarsResult<Vec<Option<f64>>> {
    let (scenes, columns): (Vec<&str>, Vec<&str>) = keys.iter().map(|(s, c)| (s.as_str(), c.as_str())).unzip();
    let ours = df!("Scene" => scenes, "column" => columns)?.with_row_index("i".into(), None)?;
    let args = JoinArgs { validation: JoinValidation::ManyToOne, ..JoinArgs::new(JoinType::Left) };
    let joined = ours
        .join(table, ["Scene", "column"], ["Scene", "column"], args, None)?
        .sort(["i"], SortMultipleOptions::default().with_maintain_order(true))?;
    Ok(joined.column("paper")?.f64()?.iter().collect())
}

/// (ours - paper) / paper * 100 per pair, NaN where paper is 0: the difference column of the
/// reference comparison.
pub fn differences(ours: &[f64], paper: &[f64]) -> PolarsResult<Vec<f64>> {
    let df = df!("ours" => ours, "paper" => paper)?;
    let (o, p) = (df.column("ours")?.f64()?, df.column("paper")?.f64()?);
    let diff = &(&(o - p) / p) * 100.0;
    let nan = Float64Chunked::full("nan".into(), f64::NAN, p.len());
    let diff = diff.zip_with(&p.not_equal(0.0), &nan)?;
    Ok(diff.iter().map(|d| d.unwrap_or(f64::NAN)).collect())
}

/// Bittner 2013 table 2 (`read_tsv`: Scene, triangles_k, method, cost, ocost, update_s, build_s)
/// inner-joined with our rows `ours` (triangles in thousands, method) on (triangles_k, method):
/// per match the paper's scene, method and values (NaN where a cell is missing) and the index into
/// `ours`, in table order, then `ours` order.
pub fn join_bittner(table: &DataFrame, ours: &[(u64, &str)]) -> PolarsResult<Vec<(String, String, [f64; 4], usize)>> {
    const VALUES: [&str; 4] = ["cost", "ocost", "update_s", "build_s"];
    let mut paper = table.select(["Scene", "method"])?.with_row_index("i".into(), None)?;
    // Counts that are not whole numbers become null and match nothing.
    paper.with_column(table.column("triangles_k")?.cast(&DataType::UInt64)?)?;
    for v in VALUES {
        let c = match table.column(v) {
            Ok(c) => c.cast(&DataType::Float64)?,
            Err(_) => Column::full_null(v.into(), table.height(), &DataType::Float64),
        };
        paper.with_column(c)?;
    }
    let ours = df!(
        "j" => (0..ours.len() as u32).collect::<Vec<_>>(),
        "triangles_k" => ours.iter().map(|o| o.0).collect::<Vec<u64>>(),
        "method" => ours.iter().map(|o| o.1).collect::<Vec<&str>>(),
    )?;
    let joined = paper
        .inner_join(&ours, ["triangles_k", "method"], ["triangles_k", "method"])?
        .sort(["i", "j"], SortMultipleOptions::default().with_maintain_order(true))?;
    let (scene, method, j) = (joined.column("Scene")?.str()?, joined.column("method")?.str()?, joined.column("j")?.u32()?);
    let values = VALUES.map(|v| joined.column(v).and_then(|c| c.f64()).cloned());
    let values: Vec<Float64Chunked> = values.into_iter().collect::<PolarsResult<_>>()?;
    Ok((0..joined.height())
        .map(|k| {
            (
                scene.get(k).unwrap_or_default().to_string(),
                method.get(k).unwrap_or_default().to_string(),
                [0, 1, 2, 3].map(|c| values[c].get(k).unwrap_or(f64::NAN)),
                j.get(k).unwrap_or_default() as usize,
            )
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pareto_front;

    fn frame(scenes: &[&str], pts: &[(f64, f64)]) -> DataFrame {
        let ids: Vec<u32> = (0..pts.len() as u32).collect();
        df!(
            "scene" => scenes,
            "id" => ids,
            "x" => pts.iter().map(|p| p.0).collect::<Vec<_>>(),
            "y" => pts.iter().map(|p| p.1).collect::<Vec<_>>(),
        )
        .unwrap()
    }

    /// The polars fronts agree with the hand-written `pareto_front` on every group, including
    /// ties, duplicates, NaN and infinities.
    #[test]
    fn polars_fronts_match_pareto_front() {
        let mut state = 0x2545f4914f6cdd1du64;
        let mut next = |n: u64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state % n
        };
        for round in 0..300 {
            let n = 1 + next(30) as usize;
            let groups = ["a", "b", "c"];
            let mut scenes = Vec::new();
            let mut pts = Vec::new();
            for _ in 0..n {
                scenes.push(groups[next(3) as usize]);
                let v = |k: u64| match k {
                    0 => f64::NAN,
                    1 => f64::INFINITY,
                    k => (k % 7) as f64 * 0.5,
                };
                pts.push((v(next(20)), v(next(20))));
            }
            let got = front_ids(&frame(&scenes, &pts), "scene", "id", "x", "y").unwrap();
            let mut want: Vec<(String, Vec<u32>)> = Vec::new();
            for g in groups.iter().filter(|g| scenes.contains(g)) {
                let idx: Vec<usize> = (0..n).filter(|&i| scenes[i] == *g).collect();
                let sub: Vec<(f64, f64)> = idx.iter().map(|&i| pts[i]).collect();
                let f: Vec<u32> = pareto_front(&sub).into_iter().map(|k| idx[k] as u32).collect();
                if !f.is_empty() {
                    want.push((g.to_string(), f));
                }
            }
            // Group order: first appearance among the rows with finite points.
            want.sort_by_key(|(g, _)| (0..n).find(|&i| scenes[i] == g && pts[i].0.is_finite() && pts[i].1.is_finite()));
            assert_eq!(got, want, "round {round}: {scenes:?} {pts:?}");
        }
    }

    /// `group_best` picks what `Iterator::min_by` over the finite values picks (the first on a tie).
    #[test]
    fn group_best_matches_min_by() {
        let scenes = ["a", "b", "a", "a", "b", "c"];
        let pts = [(2.0, 0.0), (f64::NAN, 0.0), (1.0, 0.0), (1.0, 0.0), (3.0, 0.0), (f64::INFINITY, 0.0)];
        let df = frame(&scenes, &pts);
        let lo = group_best(&df, "scene", "id", "x", false).unwrap();
        assert_eq!(lo, vec![("a".to_string(), 2, 1.0), ("b".to_string(), 4, 3.0)]);
        let hi = group_best(&df, "scene", "id", "x", true).unwrap();
        assert_eq!(hi, vec![("a".to_string(), 0, 2.0), ("b".to_string(), 4, 3.0)]);
    }
}
