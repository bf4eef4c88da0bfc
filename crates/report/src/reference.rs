//! Our results beside the Frantal 2019 thesis tables (../shared/reference/frantal_t*.tsv).
//!
//! Which of our scenes is a thesis scene comes from the data, not from names: the thesis scene list in
//! `frantal_scenes_and_variants.md` gives triangle counts, and "a scene reproduces a table row only
//! where it is the same model (same triangle count)". Scenes whose name looks like a thesis scene but
//! whose triangle count differs are listed as different models and not compared.
use crate::analysis::{on_rays, RowMetric};
use crate::frame;
use bvhlab_pipeline::ResultRow;
use polars::prelude::DataFrame;
use std::collections::BTreeMap;
use std::path::Path;

/// A thesis table column (method abbreviation) and the chain of ours that reproduces it, matched on
/// the columns builder / build_params / encoder / encode_params / compact / optimizer /
/// optimize_params (never the label).
/// `params`, `encode_params` and `optimize_params` list `k=v` pairs that must hold, alternatives
/// separated by `|`; a key missing from a row counts as the default (assumed equal), but at least
/// one key of the alternative must be present (so `preset=hq` does not match a row that spells out
/// other delta/epsilon values). A value `auto` also matches `auto:<builder>`. Adding a method is one
/// line here.
pub struct MethodMap {
    pub abbrev: &'static str,
    pub builder: &'static str,
    pub params: &'static str,
    /// `None`: any (bottom-up builders compact inside their build stage).
    pub compact: Option<&'static str>,
    /// `None`: the row must have no encode stage.
    pub encoder: Option<&'static str>,
    pub encode_params: &'static str,
    /// `None`: the row must have no optimize stage.
    pub optimizer: Option<&'static str>,
    pub optimize_params: &'static str,
}

/// A top-down (or incremental) method without encoder and optimizer.
const fn plain(abbrev: &'static str, builder: &'static str, params: &'static str, compact: &'static str) -> MethodMap {
    MethodMap { abbrev, builder, params, compact: Some(compact), encoder: None, encode_params: "", optimizer: None, optimize_params: "" }
}

/// A bottom-up method on the thesis' Morton codes (compaction inside the build stage).
const fn coded(abbrev: &'static str, builder: &'static str, params: &'static str) -> MethodMap {
    MethodMap {
        abbrev,
        builder,
        params,
        compact: None,
        encoder: Some("morton"),
        encode_params: ORIGINAL_CODES,
        optimizer: None,
        optimize_params: "",
    }
}

/// The thesis builds its Morton-code builders from plain Morton codes with the method's own code
/// length (bits=auto), quantized in the scene box, no occupation grid.
const ORIGINAL_CODES: &str = "bits=auto,bounds=scene,grid_bits=0";

/// Thesis 4.1 / reference README: FSW full-sweep SAH and BIN binned SAH (16 bins, leaf threshold 2),
/// both top-down with the SAH leaf-vs-split test and no compaction; AHQ/ALQ = AAC (table 2
/// presets), PL1-3 = PLOC radius 10/25/100, all on Morton codes and SAH-compacted; BP0-2 = Bonsai
/// (thesis table 3: N = 512 unpruned, N = 512 T = 0.1, N = 4096 T = 0.01, top-down with the
/// leaf-vs-split test); INC = incremental insertion (thesis table 5 parameters), one triangle per
/// leaf, then SAH-compacted (reference README).
pub const METHODS: &[MethodMap] = &[
    plain("FSW", "sweep-sah", "leaf=2", "none"),
    // The thesis stops binning when the centroid extent is tiny along *any* axis (3.1.1); our default
    // stops only along the split axis. The literal rule is what reproduces its BIN column.
    plain("BIN", "binned-sah", "bins=16,centroid_stop=any-axis,leaf=2", "none"),
    coded("AHQ", "aac", "delta=20,epsilon=0.1|preset=hq"),
    coded("ALQ", "aac", "delta=4,epsilon=0.2|preset=fast"),
    coded("PL1", "ploc", "radius=10"),
    coded("PL2", "ploc", "radius=25"),
    coded("PL3", "ploc", "radius=100"),
    plain("BP0", "bonsai", "n=512,prune=false,leaf=2", "none"),
    plain("BP1", "bonsai", "n=512,prune=true,t=0.1,leaf=2", "none"),
    plain("BP2", "bonsai", "n=4096,prune=true,t=0.01,leaf=2", "none"),
    plain("INC", "incremental", "batch=8000,ofrac=0.01,coh=1.5", "collapse"),
];

/// The thesis' IBO settings (reference README: iboFrac 1%, of all nodes as thesis 3.4.3 counts it:
/// `ibo_nodes=all`; pT = 10, pR = 5, combined measure) with
/// its termination (thesis 3.4.3: `schedule=thesis`) and, as in the thesis (5.2.1), the last tree
/// of the run returned (`keep_best=false`, implied by `schedule=thesis`).
const IBO_THESIS: &str = "measure=comb,ibo_frac=0.01,ibo_nodes=all,pt=10,pr=5,schedule=thesis,keep_best=false";

const fn ibo(abbrev: &'static str, builder: &'static str, params: &'static str) -> MethodMap {
    MethodMap {
        abbrev,
        builder,
        params,
        compact: Some("collapse"),
        encoder: None,
        encode_params: "",
        optimizer: Some("ibo"),
        optimize_params: IBO_THESIS,
    }
}

/// Thesis 5.2 (tables 20, 38): FSW and INC built with one triangle per leaf, BIN with its leaf
/// threshold 2, then IBO, then SAH compaction. Table 38 is the cost after; table 20 the cost after
/// relative to the non-optimized method of table 10 (FSW/BIN/INC of `METHODS`), in percent.
pub const IBO_METHODS: &[MethodMap] = &[
    ibo("FSW", "sweep-sah", "leaf=1"),
    ibo("BIN", "binned-sah", "bins=16,centroid_stop=any-axis,leaf=2"),
    ibo("INC", "incremental", "batch=8000,ofrac=0.01,coh=1.5"),
];
pub const IBO_RELATIVE_TABLE: &str = "frantal_t20_ibo_relative_percent.tsv";
pub const IBO_COST_TABLE: &str = "frantal_t38_ibo_cost_and_time.tsv";
pub const IBO_RELATIVE_LABEL: &str = "IBO: cost after / before [%] (table 20)";
pub const IBO_COST_LABEL: &str = "SAH cost after IBO + compaction (table 38)";

/// Bittner et al. 2013 table 2 (objects, SAH-built initial trees): the initial tree is a full-sweep
/// SAH build with one triangle per leaf; "cost" is that tree (after the optimizer), "ocost" the
/// same after SAH compaction. Rows name the optimizer by its measure.
pub const BITTNER_TABLE: &str = "bittner2013_t2_objects_sah_base.tsv";
pub const BITTNER_COST_LABEL: &str = "cost, one triangle per leaf (Bittner 2013 table 2)";
pub const BITTNER_OCOST_LABEL: &str = "ocost, after compaction (Bittner 2013 table 2)";

const fn bittner(abbrev: &'static str, optimizer: Option<&'static str>, optimize_params: &'static str) -> MethodMap {
    MethodMap {
        abbrev,
        builder: "sweep-sah",
        params: "leaf=1",
        compact: Some("collapse"),
        encoder: None,
        encode_params: "",
        optimizer,
        optimize_params,
    }
}

/// Bittner's own termination (Bittner 2013 3.5: `schedule=bittner`, the default).
pub const BITTNER_METHODS: &[MethodMap] = &[
    bittner("SAH build", None, ""),
    bittner("IBO random", Some("ibo"), "measure=random,schedule=bittner"),
    bittner("IBO combined", Some("ibo"), "measure=comb,schedule=bittner"),
    bittner("Kensler hill climbing", Some("kensler-hc"), ""),
    bittner("Kensler annealing", Some("kensler-sa"), ""),
];

/// One row of Bittner 2013 table 2 beside ours (times on different machines: compare ratios).
#[derive(Clone, Debug, PartialEq)]
pub struct BittnerComparison {
    pub scene_name: String,
    pub paper_scene: String,
    pub paper_method: String,
    pub method: String,
    /// cost, ocost, update_s, build_s.
    pub ours: [f64; 4],
    pub paper: [f64; 4],
    /// CPU model of our row's construction times: ratios only between rows of one model (issue 12).
    pub machine: String,
}

/// Thesis table 25: EMC-64-var relative to the original Morton codes, same builder and parameters,
/// in percent (cost and build time). Ours: emc64-var in the scene box without grid.
pub const EMC_TABLE: &str = "frantal_t25_emc64var_relative_percent.tsv";
pub const EMC_ENCODER: &str = "emc64-var";
pub const EMC_PARAMS: &str = "bounds=scene,grid_bits=0";
/// Methods of table 25 (abbreviations of `METHODS`).
pub const EMC_METHODS: &[&str] = &["AHQ", "ALQ", "PL1", "PL2", "PL3"];
pub const EMC_COST_LABEL: &str = "EMC-64-var / Morton SAH cost [%]";
pub const EMC_BUILD_LABEL: &str = "EMC-64-var / Morton build time [%]";

/// A comparison is marked as reproduced when |difference| is at most this many percent.
pub const WITHIN_PERCENT: f64 = 3.0;

/// Thesis tables 10, 15-19 (`id`: the table file). Traversal counts use the thesis' primary rays (800x800); our camera is
/// not the thesis' camera, so those compare only roughly.
pub const METRICS: &[RowMetric] = &[
    RowMetric { id: "frantal_t10_sah_cost.tsv", label: "SAH cost", rays: None, value: |r| Some(r.sah_cost) },
    RowMetric {
        id: "frantal_t15_traversal_steps_primary.tsv",
        label: "traversal steps / primary ray",
        rays: Some("primary"),
        value: |r| r.traversal_steps_per_ray,
    },
    RowMetric {
        id: "frantal_t16_intersections_primary.tsv",
        label: "intersections / primary ray",
        rays: Some("primary"),
        value: |r| r.intersections_per_ray,
    },
    RowMetric { id: "frantal_t17_refs_per_leaf.tsv", label: "refs per leaf", rays: None, value: |r| Some(r.refs_per_leaf) },
    RowMetric { id: "frantal_t18_inner_sa_ratio.tsv", label: "inner SA ratio", rays: None, value: |r| Some(r.inner_sa_ratio) },
    RowMetric { id: "frantal_t19_leaf_sa_ratio.tsv", label: "leaf SA ratio", rays: None, value: |r| Some(r.leaf_sa_ratio) },
];

const SCENES_MD: &str = "frantal_scenes_and_variants.md";
/// The table whose row order defines the short scene names (the md lists the same scenes in order).
const INDEX_TABLE: &str = "frantal_t10_sah_cost.tsv";

#[derive(Clone, Debug, PartialEq)]
pub struct Comparison {
    /// Whose table: `Frantal 2019` (thesis) or `Bittner 2013`.
    pub source: String,
    pub metric: String,
    pub scene_name: String,
    pub thesis_scene: String,
    pub abbrev: String,
    pub method: String,
    pub ours: f64,
    pub paper: f64,
    /// (ours - paper) / paper * 100.
    pub diff_percent: f64,
}

impl Comparison {
    /// |difference| <= `WITHIN_PERCENT`.
    pub fn within(&self) -> bool {
        self.diff_percent.is_finite() && self.diff_percent.abs() <= WITHIN_PERCENT
    }
}

#[derive(Debug, Default)]
pub struct ReferenceReport {
    pub comparisons: Vec<Comparison>,
    /// Why something was not compared (different model, other cost constants, missing tables).
    pub notes: Vec<String>,
    /// Bittner 2013 table 2 rows beside ours (cost, ocost, update_s, build_s).
    pub bittner: Vec<BittnerComparison>,
}

/// A thesis scene: short name as in the tables, full name and triangle count from the md.
#[derive(Clone, Debug)]
struct ThesisScene {
    short: String,
    full: String,
    triangles: u64,
}

/// The scenes of a thesis table in row order (its first column), read with polars.
fn tsv_scene_order(path: &Path) -> Result<Vec<String>, String> {
    let table = frame::read_tsv(path)?;
    let first = table.columns().first().ok_or_else(|| format!("{}: empty table", path.display()))?;
    let scenes = first.str().map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(scenes.iter().flatten().map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect())
}

/// Markdown rows `| name | 871 414 | kind |` whose second cell is a (space-grouped) integer.
fn md_scenes(text: &str) -> Vec<(String, u64)> {
    text.lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.trim().trim_matches('|').split('|').map(str::trim).collect();
            if cells.len() < 2 {
                return None;
            }
            let digits: String = cells[1].chars().filter(|c| !c.is_whitespace() && *c != ',').collect();
            if digits.is_empty() || !digits.chars().all(|c| c.is_ascii_digit()) {
                return None;
            }
            Some((cells[0].to_string(), digits.parse().ok()?))
        })
        .collect()
}

/// `c_T = 3.0` style settings in the md text.
fn md_constant(text: &str, name: &str) -> Option<f64> {
    let pat = format!("{name} = ");
    let start = text.find(&pat)? + pat.len();
    let num: String =
        text[start..].chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
    num.trim_end_matches('.').parse().ok()
}

fn thesis_scenes(dir: &Path) -> Result<(Vec<ThesisScene>, String), String> {
    let md_path = dir.join(SCENES_MD);
    let md = std::fs::read_to_string(&md_path).map_err(|e| format!("{}: {e}", md_path.display()))?;
    let listed = md_scenes(&md);
    let order = tsv_scene_order(&dir.join(INDEX_TABLE))?;
    if listed.len() != order.len() {
        return Err(format!(
            "{} lists {} scenes but {} has {} rows; cannot pair short and full scene names",
            SCENES_MD,
            listed.len(),
            INDEX_TABLE,
            order.len()
        ));
    }
    let scenes = order
        .into_iter()
        .zip(listed)
        .map(|(short, (full, triangles))| ThesisScene { short, full, triangles })
        .collect();
    Ok((scenes, md))
}

/// The thesis scene this row's scene is (same triangle count, loaded from a file), if any.
fn same_model<'a>(row: &ResultRow, scenes: &'a [ThesisScene]) -> Option<&'a ThesisScene> {
    if row.scene.starts_with("gen:") {
        return None;
    }
    let loaded = row.triangles + row.dropped_triangles;
    scenes.iter().find(|s| s.triangles == loaded || s.triangles == row.triangles)
}

/// A thesis scene whose name shares a word (5+ letters) with ours: likely the same subject, but a
/// different model when the triangle counts differ.
fn look_alike<'a>(scene_name: &str, scenes: &'a [ThesisScene]) -> Option<&'a ThesisScene> {
    let words: Vec<String> = scene_name
        .split(|c: char| !c.is_ascii_alphabetic())
        .filter(|w| w.len() >= 5)
        .map(|w| w.to_ascii_lowercase())
        .collect();
    scenes.iter().find(|s| {
        let full = s.full.to_ascii_lowercase();
        words.iter().any(|w| full.split(|c: char| !c.is_ascii_alphabetic()).any(|f| f == w))
    })
}

fn value_match(have: &str, want: &str) -> bool {
    have == want || (want == "auto" && have.starts_with("auto:"))
}

/// One alternative (`k=v,...`): every key present in the row has the wanted value, and at least one
/// wanted key is present unless the row has no parameters at all (all defaults).
fn alternative_match(row_params: &str, wanted: &str) -> bool {
    let have: BTreeMap<&str, &str> =
        row_params.split(',').filter_map(|kv| kv.split_once('=')).collect();
    let want: Vec<(&str, &str)> = wanted.split(',').filter_map(|kv| kv.split_once('=')).collect();
    let present = want.iter().filter(|(k, _)| have.contains_key(k)).count();
    (present > 0 || have.is_empty() || want.is_empty())
        && want.iter().all(|(k, v)| have.get(k).is_none_or(|h| value_match(h, v)))
}

/// `wanted` is a `|`-separated list of alternatives; any one matching is enough.
fn params_match(row_params: &str, wanted: &str) -> bool {
    wanted.split('|').any(|alt| alternative_match(row_params, alt))
}

fn extra_params(row_params: &str, wanted: &str) -> usize {
    let wanted: Vec<&str> = wanted
        .split(['|', ','])
        .filter_map(|kv| kv.split_once('='))
        .map(|p| p.0)
        .collect();
    row_params
        .split(',')
        .filter_map(|kv| kv.split_once('='))
        .filter(|(k, _)| !wanted.contains(k))
        .count()
}

/// Whether row `r` is a run of thesis method `m` (builder, parameters, encoder, optimizer,
/// compaction); the number of parameters beyond the mapping (fewer = better match) if so.
pub fn row_matches(r: &ResultRow, m: &MethodMap) -> Option<usize> {
    if r.builder != m.builder || !params_match(&r.build_params, m.params) {
        return None;
    }
    if m.compact.is_some_and(|c| c != r.compact) {
        return None;
    }
    // An optional stage (encode, optimize): absent on both sides, or the same method with matching
    // parameters (the count beyond the mapping).
    let stage = |want: Option<&str>, have: Option<&str>, have_params: Option<&str>, wanted: &str| match (want, have) {
        (None, None) => Some(0),
        (Some(want), Some(have)) if want == have => {
            let p = have_params.unwrap_or("");
            params_match(p, wanted).then(|| extra_params(p, wanted))
        }
        _ => None,
    };
    let encode_extra = stage(m.encoder, r.encoder.as_deref(), r.encode_params.as_deref(), m.encode_params)?;
    let optimize_extra = stage(m.optimizer, r.optimizer.as_deref(), r.optimize_params.as_deref(), m.optimize_params)?;
    Some(extra_params(&r.build_params, m.params) + encode_extra + optimize_extra)
}

/// Compares every row that reproduces a thesis (scene, method) cell. Missing optional tables are
/// skipped with a note; a missing scene list or SAH table is an error.
pub fn compare(dir: &Path, rows: &[ResultRow]) -> Result<ReferenceReport, String> {
    let mut rep = ReferenceReport::default();
    let (scenes, md) = thesis_scenes(dir)?;
    let c_t = md_constant(&md, "c_T");
    let c_i = md_constant(&md, "c_I");

    // Scene-level decisions, once per scene, in row order.
    let mut seen = std::collections::BTreeSet::new();
    for r in rows {
        if !seen.insert(r.scene.clone()) || same_model(r, &scenes).is_some() {
            continue;
        }
        if let Some(t) = look_alike(&r.scene_name, &scenes) {
            rep.notes.push(format!(
                "{}: {} triangles, the thesis' {} has {}: a different model, not compared.",
                r.scene_name, r.triangles, t.full, t.triangles
            ));
        }
    }

    // The thesis' numbers are for its cost constants; other constants give other trees.
    let consts_ok = |r: &ResultRow| c_t.is_none_or(|c| c == r.c_t) && c_i.is_none_or(|c| c == r.c_i);
    if rows.iter().any(|r| {
        same_model(r, &scenes).is_some() && !consts_ok(r) && METHODS.iter().any(|m| row_matches(r, m).is_some())
    }) {
        rep.notes.push(format!(
            "Rows with c_t/c_i other than the thesis' ({}/{}) are not compared.",
            c_t.map_or("?".into(), |c| c.to_string()),
            c_i.map_or("?".into(), |c| c.to_string())
        ));
    }
    // Best row per (scene, abbrev): fewest parameters beyond the mapping, then first.
    let select = |rays: Option<&str>, methods: &'static [MethodMap]| -> Vec<((String, &'static str), usize)> {
        let mut best: BTreeMap<(String, &'static str), (usize, usize)> = BTreeMap::new();
        let mut order: Vec<(String, &'static str)> = Vec::new();
        for (ri, r) in rows.iter().enumerate() {
            if same_model(r, &scenes).is_none() || !consts_ok(r) {
                continue;
            }
            if !on_rays(r, rays) {
                continue;
            }
            for m in methods {
                let Some(extra) = row_matches(r, m) else { continue };
                let key = (r.scene.clone(), m.abbrev);
                match best.get(&key) {
                    Some(&(e, _)) if e <= extra => {}
                    None => {
                        order.push(key.clone());
                        best.insert(key, (extra, ri));
                    }
                    Some(_) => {
                        best.insert(key, (extra, ri));
                    }
                }
            }
        }
        order.into_iter().map(|k| (k.clone(), best[&k].1)).collect()
    };

    // Every comparison is a left join of our cells (the thesis scene and table column of a
    // selected row) on a paper table read with polars (`frame::read_paper_table`, `frame::lookup`);
    // the differences are computed at the end, on one polars frame (`frame::differences`).
    let push = |rep: &mut ReferenceReport, metric: &str, r: &ResultRow, ts: &ThesisScene, abbrev: &str, method: String, ours: f64, paper: f64| {
        rep.comparisons.push(Comparison {
            source: THESIS.to_string(),
            metric: metric.to_string(),
            scene_name: r.scene_name.clone(),
            thesis_scene: ts.short.clone(),
            abbrev: abbrev.to_string(),
            method,
            ours,
            paper,
            diff_percent: f64::NAN,
        });
    };
    // The selected rows of thesis scenes, with the table column each reads.
    let cells = |rays: Option<&str>, methods: &'static [MethodMap], column: &dyn Fn(&str) -> String| {
        select(rays, methods)
            .into_iter()
            .filter_map(|((scene, abbrev), ri)| {
                let ts = same_model(&rows[ri], &scenes)?;
                Some((scene, abbrev, ri, ts, (ts.short.clone(), column(abbrev))))
            })
            .collect::<Vec<_>>()
    };
    let keys = |cells: &[(String, &str, usize, &ThesisScene, (String, String))]| -> Vec<(String, String)> {
        cells.iter().map(|c| c.4.clone()).collect()
    };

    for metric in METRICS {
        let path = dir.join(metric.id);
        if !path.exists() {
            rep.notes.push(format!("{} not found: {} not compared.", metric.id, metric.label));
            continue;
        }
        let table = frame::read_paper_table(&path)?;
        let cells = cells(metric.rays, METHODS, &|abbrev| abbrev.to_string());
        let papers = frame::lookup(&table, &keys(&cells)).map_err(polars_error)?;
        for ((_, abbrev, ri, ts, _), paper) in cells.into_iter().zip(papers) {
            let r = &rows[ri];
            let Some(paper) = paper else { continue };
            let Some(ours) = (metric.value)(r).filter(|v| v.is_finite()) else { continue };
            push(&mut rep, metric.label, r, ts, abbrev, r.method.clone(), ours, paper);
        }
    }

    // Table 25: EMC-64-var relative to the Morton row of the same builder and parameters.
    let emc_table = optional_table(dir, EMC_TABLE, "EMC-64-var ratios", &mut rep)?;
    let mut emc_cells = Vec::new();
    for (scene, abbrev, mi, ts, _) in cells(None, METHODS, &|_| String::new()) {
        if !EMC_METHODS.contains(&abbrev) {
            continue;
        }
        let m = &rows[mi];
        let emc = rows
            .iter()
            .filter(|r| {
                r.scene == scene
                    && r.builder == m.builder
                    && r.build_params == m.build_params
                    && r.compact == m.compact
                    && r.optimizer == m.optimizer
                    && consts_ok(r)
                    && r.encoder.as_deref() == Some(EMC_ENCODER)
                    && params_match(r.encode_params.as_deref().unwrap_or(""), EMC_PARAMS)
            })
            .min_by_key(|r| extra_params(r.encode_params.as_deref().unwrap_or(""), EMC_PARAMS));
        let Some(e) = emc else { continue };
        let method = format!("{} / {}", e.method, m.method);
        let ratio = |a: f64, b: f64| if b > 0.0 && a.is_finite() && b.is_finite() { Some(100.0 * a / b) } else { None };
        let cost = ratio(e.sah_cost, m.sah_cost);
        // A time ratio only between rows timed on one CPU model (issue 12).
        let build = if crate::analysis::same_build_machine(e, m) {
            ratio(crate::analysis::total_build_seconds(e), crate::analysis::total_build_seconds(m))
        } else {
            None
        };
        for (label, col, ours) in [(EMC_COST_LABEL, "cost", cost), (EMC_BUILD_LABEL, "build", build)] {
            if let Some(ours) = ours {
                emc_cells.push((label, m, ts, abbrev, method.clone(), ours, (ts.short.clone(), format!("{col}_{abbrev}"))));
            }
        }
    }
    let emc_keys: Vec<(String, String)> = emc_cells.iter().map(|c| c.6.clone()).collect();
    let papers = frame::lookup(&emc_table, &emc_keys).map_err(polars_error)?;
    for ((label, m, ts, abbrev, method, ours, _), paper) in emc_cells.into_iter().zip(papers) {
        if let Some(paper) = paper {
            push(&mut rep, label, m, ts, abbrev, method, ours, paper);
        }
    }

    // Tables 38 and 20: IBO chains, absolute and relative to the table-10 method.
    let t38 = optional_table(dir, IBO_COST_TABLE, "IBO costs (table 38)", &mut rep)?;
    let t20 = optional_table(dir, IBO_RELATIVE_TABLE, "IBO relative costs (table 20)", &mut rep)?;
    let before = select(None, METHODS);
    let ibo = cells(None, IBO_METHODS, &|abbrev| format!("cost_{abbrev}"));
    let p38 = frame::lookup(&t38, &keys(&ibo)).map_err(polars_error)?;
    let p20 = frame::lookup(&t20, &keys(&ibo)).map_err(polars_error)?;
    for (((scene, abbrev, ri, ts, _), p38), p20) in ibo.into_iter().zip(p38).zip(p20) {
        let r = &rows[ri];
        if let Some(paper) = p38 {
            if r.sah_cost.is_finite() {
                push(&mut rep, IBO_COST_LABEL, r, ts, abbrev, r.method.clone(), r.sah_cost, paper);
            }
        }
        let Some(paper) = p20 else { continue };
        let Some(&(_, bi)) = before.iter().find(|((s, a), _)| *s == scene && *a == abbrev) else {
            rep.notes.push(format!(
                "{}: table 20 {abbrev} needs the non-optimized {abbrev} chain of table 10 to divide by; not in this experiment.",
                r.scene_name
            ));
            continue;
        };
        let b = &rows[bi];
        if b.sah_cost > 0.0 && r.sah_cost.is_finite() {
            let method = format!("{} / {}", r.method, b.method);
            push(&mut rep, IBO_RELATIVE_LABEL, r, ts, abbrev, method, 100.0 * r.sah_cost / b.sah_cost, paper);
        }
    }

    bittner_compare(dir, rows, &mut rep)?;
    let (ours, paper): (Vec<f64>, Vec<f64>) = rep.comparisons.iter().map(|c| (c.ours, c.paper)).unzip();
    let diffs = frame::differences(&ours, &paper).map_err(polars_error)?;
    for (c, d) in rep.comparisons.iter_mut().zip(diffs) {
        c.diff_percent = d;
    }
    Ok(rep)
}

pub const THESIS: &str = "Frantal 2019";
pub const BITTNER: &str = "Bittner 2013";

fn polars_error(e: polars::prelude::PolarsError) -> String {
    format!("reference tables: {e}")
}

/// A paper table that may be missing (a note instead of an error; an empty table then).
fn optional_table(dir: &Path, file: &str, what: &str, rep: &mut ReferenceReport) -> Result<DataFrame, String> {
    let path = dir.join(file);
    if path.exists() {
        frame::read_paper_table(&path)
    } else {
        rep.notes.push(format!("{file} not found: {what} not compared."));
        frame::empty_paper_table().map_err(polars_error)
    }
}

/// Bittner 2013 "cost" of a row: the tree before compaction (after the optimizer, or as built).
pub fn bittner_cost(r: &ResultRow) -> Option<f64> {
    if r.optimizer.is_some() {
        r.optimized_sah_cost
    } else if r.compact == "none" {
        Some(r.sah_cost)
    } else {
        r.build_sah_cost
    }
}

/// Bittner 2013 table 2: rows of scenes with the paper's triangle count (in thousands, rounded),
/// matched by `BITTNER_METHODS`; cost and ocost also as comparisons, times only in the table (other
/// machine). Polars: the table (read with the csv reader) inner-joined with our best row per scene
/// and method on (triangles_k, method), in table order, then our scenes' order.
fn bittner_compare(dir: &Path, rows: &[ResultRow], rep: &mut ReferenceReport) -> Result<(), String> {
    let path = dir.join(BITTNER_TABLE);
    if !path.exists() {
        if rows.iter().any(|r| r.optimizer.is_some()) {
            rep.notes.push(format!("{BITTNER_TABLE} not found: Bittner 2013 table 2 not compared."));
        }
        return Ok(());
    }
    let table = frame::read_tsv(&path)?;
    // Ours: per scene (in row order) and method, the row matching it with the fewest extra parameters.
    let thousands = |r: &ResultRow| ((r.triangles + r.dropped_triangles) as f64 / 1000.0).round() as u64;
    let paper_consts = |r: &&ResultRow| r.c_t == 3.0 && r.c_i == 2.0;
    let mut scenes: Vec<&ResultRow> = Vec::new();
    for r in rows.iter().filter(|r| !r.scene.starts_with("gen:")).filter(paper_consts) {
        if !scenes.iter().any(|s| s.scene == r.scene) {
            scenes.push(r);
        }
    }
    let mut ours: Vec<(u64, &'static str, &ResultRow)> = Vec::new();
    for s in &scenes {
        for m in BITTNER_METHODS {
            let best = rows
                .iter()
                .filter(|r| r.scene == s.scene)
                .filter(paper_consts)
                .filter_map(|r| row_matches(r, m).map(|e| (e, r)))
                .min_by_key(|(e, _)| *e);
            if let Some((_, r)) = best {
                ours.push((thousands(s), m.abbrev, r));
            }
        }
    }
    let keys: Vec<(u64, &str)> = ours.iter().map(|o| (o.0, o.1)).collect();
    let joined = frame::join_bittner(&table, &keys).map_err(|e| format!("{}: {e}", path.display()))?;
    for (paper_scene, paper_method, paper, j) in joined {
        let r = ours[j].2;
        let ours = [
            bittner_cost(r).unwrap_or(f64::NAN),
            r.sah_cost,
            // Times of a row whose stages ran on different CPU models are not comparable.
            if r.build_machine.contains(" + ") { f64::NAN } else { r.optimize_seconds.unwrap_or(0.0) },
            if r.build_machine.contains(" + ") {
                f64::NAN
            } else {
                crate::analysis::total_build_seconds(r) - r.compact_seconds
            },
        ];
        for (label, o, p) in [(BITTNER_COST_LABEL, ours[0], paper[0]), (BITTNER_OCOST_LABEL, ours[1], paper[1])] {
            if o.is_finite() && p.is_finite() {
                rep.comparisons.push(Comparison {
                    source: BITTNER.to_string(),
                    metric: label.to_string(),
                    scene_name: r.scene_name.clone(),
                    thesis_scene: paper_scene.clone(),
                    abbrev: paper_method.clone(),
                    method: r.method.clone(),
                    ours: o,
                    paper: p,
                    diff_percent: f64::NAN,
                });
            }
        }
        rep.bittner.push(BittnerComparison {
            scene_name: r.scene_name.clone(),
            paper_scene,
            paper_method,
            method: r.method.clone(),
            ours,
            paper,
            machine: r.build_machine.clone(),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn md_parsing() {
        let md = "All SAH costs use c_T = 3.0 (traversal) and c_I = 2.0.\n\
                  | scene | triangles | kind |\n|---|---|---|\n| Dragon (Chinese) | 871 414 | object |\n\
                  | FSW | full sweep | - |\n";
        assert_eq!(md_scenes(md), vec![("Dragon (Chinese)".to_string(), 871_414)]);
        assert_eq!(md_constant(md, "c_T"), Some(3.0));
        assert_eq!(md_constant(md, "c_I"), Some(2.0));
        assert_eq!(md_constant(md, "c_X"), None);
    }

    #[test]
    fn param_matching() {
        assert!(params_match("bins=16,leaf=2", "bins=16,leaf=2"));
        assert!(params_match("bins=16", "bins=16,leaf=2"), "missing key = default");
        assert!(!params_match("bins=32,leaf=2", "bins=16,leaf=2"));
        assert!(params_match("", "leaf=2"));
        assert_eq!(extra_params("bins=16,leaf=2,axis=all", "bins=16,leaf=2"), 1);
        // Alternatives; a wanted key must be present unless the row is all defaults.
        assert!(params_match("delta=20,epsilon=0.1", "delta=20,epsilon=0.1|preset=hq"));
        assert!(params_match("preset=hq", "delta=20,epsilon=0.1|preset=hq"));
        assert!(!params_match("delta=4,epsilon=0.2", "delta=20,epsilon=0.1|preset=hq"));
        assert!(!params_match("radius=25", "radius=10"));
        // `auto` matches the builder-resolved `auto:aac`, a number does not.
        assert!(params_match("bits=auto:aac,bounds=scene,grid_bits=0", "bits=auto,bounds=scene,grid_bits=0"));
        assert!(!params_match("bits=10,bounds=scene,grid_bits=0", "bits=auto,bounds=scene,grid_bits=0"));
        assert!(!params_match("bits=auto:ploc,bounds=scene,grid_bits=9", "bits=auto,bounds=scene,grid_bits=0"));
        assert_eq!(extra_params("delta=20,epsilon=0.1,x=1", "delta=20,epsilon=0.1|preset=hq"), 1);
    }

    #[test]
    fn look_alikes() {
        let scenes = vec![
            ThesisScene { short: "Armadillo".into(), full: "Armadillo".into(), triangles: 345_944 },
            ThesisScene { short: "Sponza L.".into(), full: "Sponza Large".into(), triangles: 262_267 },
        ];
        assert_eq!(look_alike("armadillo_86k", &scenes).map(|s| s.triangles), Some(345_944));
        assert_eq!(look_alike("crytek_sponza_partial", &scenes).map(|s| s.triangles), Some(262_267));
        assert!(look_alike("bunny", &scenes).is_none());
    }
}
