//! Findings: Kilian's qualitative claims checked per case, under the noise and degenerate rules.
use super::rows::{label_of, short};
use super::{
    cases, Case, Point, ALMOST_AS_FAST, OCTREE_1BIT_BITS_16, QBVH_CHUNKS_TARGET_SLOWDOWN, QBVH_CHUNKS_TOPOLOGY_RATIO,
    TIE_PERCENT,
};
use crate::plots::fmt_num;
use bvhlab_pipeline::ResultRow;
use std::collections::BTreeMap;

// ---------------------------------------------------------------------------------------------
// Findings

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Agrees,
    Differs,
    /// Exactly equal deterministic quantities (bytes, tests per ray): neither.
    Tie,
    /// Timings whose difference does not exceed the measured noise (`beyond_noise`), or a timing
    /// without a measured spread (one run): neither confirmed nor contradicted.
    WithinNoise,
    /// A degenerate case (`degenerate`: empty, or a one-node structure) the claim does not speak
    /// about: a collapsed one-node octree has 0 bits per node without saying anything about
    /// Kilian's 2 bits per node.
    NotApplicable,
}

impl Verdict {
    pub fn word(self) -> &'static str {
        match self {
            Verdict::Agrees => "agrees",
            Verdict::Differs => "differs",
            Verdict::Tie => "tie",
            Verdict::WithinNoise => "within noise",
            Verdict::NotApplicable => "not applicable",
        }
    }
}

/// A timed quantity as a row reports it: the median and its spread ((max - min) / median over its
/// runs, `X_spread`; None: fewer than two runs, the noise was not measured).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timed {
    pub value: f64,
    pub spread: Option<f64>,
}

impl Timed {
    /// An exact number (a stated limit or target): no noise.
    pub fn exact(value: f64) -> Timed {
        Timed { value, spread: Some(0.0) }
    }

    /// The ratio of two timed quantities; its spread is the sum of theirs (to first order the
    /// relative range of a ratio is at most the sum of the relative ranges).
    pub fn ratio(self, b: Timed) -> Timed {
        Timed {
            value: self.value / b.value,
            spread: self.spread.zip(b.spread).map(|(x, y)| x + y),
        }
    }
}

/// The noise rule (issue 16). Two timed quantities `a` and `b` are told apart only when
///
/// ```text
/// |a / b - 1| > max(spread_a + spread_b, TIE_PERCENT / 100)
/// ```
///
/// where `spread` = (max - min) / median over each one's runs (a stated limit has spread 0). The
/// ratio must leave the band the two quantities' own run-to-run ranges span together (the sum of
/// the relative ranges bounds the relative range of their ratio to first order), and never by less
/// than `TIE_PERCENT`. A quantity without a measured spread (one run) resolves nothing: its noise
/// is unknown. Returns `Some(a / b)` when the difference is beyond the noise, `None` when it is
/// within noise (or a value is not a positive finite number).
pub fn beyond_noise(a: Timed, b: Timed) -> Option<f64> {
    let ok = |x: f64| x.is_finite() && x > 0.0;
    if !ok(a.value) || !ok(b.value) {
        return None;
    }
    let noise = a.spread.zip(b.spread).map(|(x, y)| x + y)?;
    let r = a.value / b.value;
    ((r - 1.0).abs() > noise.max(TIE_PERCENT / 100.0)).then_some(r)
}

/// The degenerate rule (issue 16): a structure with fewer than two nodes (no triangles, a one-leaf
/// BVH, a collapsed one-node octree) or no topology bytes has nothing to compress or to traverse;
/// every claim about it reads "not applicable" instead of agreeing vacuously (0 bits per node is not
/// "<= 2 bits per node" in Kilian's sense).
pub fn degenerate(r: &ResultRow) -> bool {
    r.triangles == 0
        || r.inner_nodes + r.leaves <= 1
        || r.layout_nodes.is_some_and(|n| n <= 1)
        || r.topology_bytes == Some(0)
}

fn not_applicable(case: String, rows: &[&ResultRow]) -> CaseVerdict {
    let why: Vec<String> = rows
        .iter()
        .filter(|r| degenerate(r))
        .map(|r| {
            format!(
                "{} degenerate: {} triangles, {} BVH nodes, {} layout nodes",
                r.layout.as_deref().unwrap_or("bvh"),
                r.triangles,
                r.inner_nodes + r.leaves,
                r.layout_nodes.map(|n| n.to_string()).unwrap_or_else(|| "n/a".into())
            )
        })
        .collect();
    CaseVerdict { case, verdict: Verdict::NotApplicable, numbers: why.join("; ") }
}

#[derive(Clone, Debug)]
pub struct CaseVerdict {
    pub case: String,
    pub verdict: Verdict,
    /// Our numbers behind the verdict.
    pub numbers: String,
}

#[derive(Clone, Debug)]
pub struct Finding {
    pub id: &'static str,
    pub claim: String,
    /// What Kilian states (section), or the issue's target.
    pub kilian: String,
    pub cases: Vec<CaseVerdict>,
}

/// The time a layout's ray trace is compared by: the slowdown against bvh2 timed alternately in
/// the same run when present (robust to machine load between stages), else the trace seconds; with
/// the matching spread.
fn speed(r: &ResultRow) -> Option<Timed> {
    let ok = |v: &f64| v.is_finite() && *v > 0.0;
    match r.slowdown.filter(ok) {
        Some(s) => Some(Timed { value: s, spread: r.slowdown_spread }),
        None => r.trace_seconds.filter(ok).map(|t| Timed { value: t, spread: r.trace_seconds_spread }),
    }
}

/// `1.23x bvh2 (spread 4.0%)`, or `(1 run)` without a measured spread.
fn fmt_timed(t: Timed, word: &str) -> String {
    match t.spread {
        Some(s) => format!("{}{word} (spread {:.1}%)", fmt_num(t.value), s * 100.0),
        None => format!("{}{word} (1 run: noise not measured)", fmt_num(t.value)),
    }
}

fn speed_word(r: &ResultRow) -> &'static str {
    if r.slowdown.is_some() {
        "x bvh2"
    } else {
        "s"
    }
}

/// `a` faster than `b`: agrees when a is below b beyond the noise (`beyond_noise`), differs when
/// above it, else within noise.
pub fn faster(a: Timed, b: Timed) -> Verdict {
    match beyond_noise(a, b) {
        None => Verdict::WithinNoise,
        Some(r) if r < 1.0 => Verdict::Agrees,
        Some(_) => Verdict::Differs,
    }
}

/// The claim "`a` <= `limit`" on a timed quantity: agrees when a is below the limit beyond the
/// noise, differs when above it, within noise when the limit lies inside a's noise band.
pub fn at_most(a: Timed, limit: f64) -> Verdict {
    match beyond_noise(a, Timed::exact(limit)) {
        None => Verdict::WithinNoise,
        Some(r) if r < 1.0 => Verdict::Agrees,
        Some(_) => Verdict::Differs,
    }
}

fn get(p: &Point, k: &str) -> Option<String> {
    p.params.get(k).cloned()
}

fn chunk_of(p: &Point) -> f64 {
    p.params.get("chunk_bytes").and_then(|v| v.parse().ok()).unwrap_or(f64::NAN)
}

/// Chunk-size groups of a layout: points equal except for chunk_bytes, two or more sizes.
fn chunk_groups<'c, 'a>(case: &'c Case<'a>, layout: &str) -> Vec<Vec<&'c Point<'a>>> {
    let mut groups: Vec<(BTreeMap<String, String>, Vec<&Point>)> = Vec::new();
    for p in case.points.iter().filter(|p| p.layout == layout && chunk_of(p).is_finite()) {
        let mut rest = p.params.clone();
        rest.remove("chunk_bytes");
        match groups.iter_mut().find(|g| g.0 == rest) {
            Some(g) => g.1.push(p),
            None => groups.push((rest, vec![p])),
        }
    }
    groups
        .into_iter()
        .filter(|g| g.1.len() > 1)
        .map(|(_, mut v)| {
            v.sort_by(|a, b| chunk_of(a).total_cmp(&chunk_of(b)));
            v
        })
        .collect()
}

/// Combines pair verdicts: any difference differs; else any agreement agrees; else any pair within
/// noise; else any not applicable; else tie.
fn combine(vs: &[Verdict]) -> Verdict {
    [Verdict::Differs, Verdict::Agrees, Verdict::WithinNoise, Verdict::NotApplicable]
        .into_iter()
        .find(|v| vs.contains(v))
        .unwrap_or(Verdict::Tie)
}

fn smaller_chunks(cases: &[Case], layout: &'static str, what: &'static str) -> Finding {
    let speed_claim = what == "faster";
    let mut out = Vec::new();
    for c in cases {
        for g in chunk_groups(c, layout) {
            let mut vs = Vec::new();
            let mut nums = Vec::new();
            for p in &g {
                let v = if speed_claim {
                    speed(p.row).map(|t| fmt_timed(t, speed_word(p.row)))
                } else {
                    p.row.topology_bytes_per_triangle.map(|v| format!("{} B/tri", fmt_num(v)))
                };
                nums.push(format!("{}B: {}", fmt_num(chunk_of(p)), v.unwrap_or_else(|| "n/a".into())));
            }
            for w in g.windows(2) {
                if degenerate(w[0].row) || degenerate(w[1].row) {
                    vs.push(Verdict::NotApplicable);
                } else if speed_claim {
                    if let (Some(a), Some(b)) = (speed(w[0].row), speed(w[1].row)) {
                        vs.push(faster(a, b));
                    }
                } else if let (Some(a), Some(b)) =
                    (w[0].row.topology_bytes_per_triangle, w[1].row.topology_bytes_per_triangle)
                {
                    vs.push(if a < b {
                        Verdict::Agrees
                    } else if a == b {
                        Verdict::Tie
                    } else {
                        Verdict::Differs
                    });
                }
            }
            if vs.is_empty() {
                continue;
            }
            if vs.contains(&Verdict::NotApplicable) {
                let rows: Vec<&ResultRow> = g.iter().map(|p| p.row).collect();
                let mut v = not_applicable(String::new(), &rows);
                v.numbers = format!("{}; {}", nums.join(", "), v.numbers);
                vs = vec![Verdict::NotApplicable];
                nums = vec![v.numbers];
            }
            let fixed: Vec<String> = g[0]
                .params
                .iter()
                .filter(|(k, _)| *k != "chunk_bytes" && g.len() > 1)
                .filter(|(k, v)| c.points.iter().any(|q| q.layout == layout && q.params.get(*k) != Some(*v)))
                .map(|(k, v)| short(k, v))
                .collect();
            let label = if fixed.is_empty() { c.label.clone() } else { format!("{} ({})", c.label, fixed.join(" ")) };
            out.push(CaseVerdict { case: label, verdict: combine(&vs), numbers: nums.join(", ") });
        }
    }
    let (kilian, claim) = if speed_claim {
        (
            if layout == "octree_1bit" { "4.2.4, fig. 4.15: 16 B fastest" } else { "5.2.3, fig. 5.3: 64 B faster than 128 B" },
            format!("{layout}: smaller chunks are faster (beyond the measured noise)"),
        )
    } else {
        (
            if layout == "octree_1bit" {
                "4.2.4, fig. 4.15/4.16: topology smallest at 16 B"
            } else {
                "5.2.3, fig. 5.3/5.4: 64 B smaller than 128 B"
            },
            format!("{layout}: smaller chunks give a smaller topology"),
        )
    };
    let id = match (layout, speed_claim) {
        ("octree_1bit", false) => "1a",
        ("octree_1bit", true) => "1b",
        (_, false) => "1c",
        (_, true) => "1d",
    };
    Finding { id, claim, kilian: kilian.into(), cases: out }
}

/// Pairs of qbvh_chunks points differing only in `frame` (chunk, parent).
fn frame_pairs<'c, 'a>(c: &'c Case<'a>) -> Vec<(&'c Point<'a>, &'c Point<'a>)> {
    let mut out = Vec::new();
    for a in c.points.iter().filter(|p| p.layout == "qbvh_chunks" && get(p, "frame").as_deref() == Some("chunk")) {
        let mut rest = a.params.clone();
        rest.remove("frame");
        for b in c.points.iter().filter(|p| p.layout == "qbvh_chunks" && get(p, "frame").as_deref() == Some("parent")) {
            let mut rb = b.params.clone();
            rb.remove("frame");
            if rb == rest {
                out.push((a, b));
            }
        }
    }
    out
}

fn pair_label(c: &Case, a: &Point) -> String {
    let mut p = a.params.clone();
    p.remove("frame");
    let keys: Vec<String> = p.keys().cloned().collect();
    format!("{} ({})", c.label, label_of("qbvh_chunks", &p, &keys).trim_start_matches("qbvh_chunks "))
}

fn frames(cases: &[Case]) -> (Finding, Finding) {
    let (mut fast, mut tests) = (Vec::new(), Vec::new());
    for c in cases {
        for (a, b) in frame_pairs(c) {
            let na = degenerate(a.row) || degenerate(b.row);
            if let (Some(sa), Some(sb)) = (speed(a.row), speed(b.row)) {
                fast.push(if na {
                    not_applicable(pair_label(c, a), &[a.row, b.row])
                } else {
                    CaseVerdict {
                        case: pair_label(c, a),
                        verdict: faster(sa, sb),
                        numbers: format!(
                            "chunk {}, parent {}",
                            fmt_timed(sa, speed_word(a.row)),
                            fmt_timed(sb, speed_word(b.row))
                        ),
                    }
                });
            }
            let t = |r: &ResultRow| r.intersections_per_ray.or(r.extra_tests_per_ray).filter(|v| v.is_finite());
            if let (Some(ta), Some(tb)) = (t(a.row), t(b.row)) {
                if na {
                    tests.push(not_applicable(pair_label(c, a), &[a.row, b.row]));
                    continue;
                }
                let v = if tb < ta {
                    Verdict::Agrees
                } else if tb == ta {
                    Verdict::Tie
                } else {
                    Verdict::Differs
                };
                tests.push(CaseVerdict {
                    case: pair_label(c, a),
                    verdict: v,
                    numbers: format!("tests/ray: chunk {}, parent {}", fmt_num(ta), fmt_num(tb)),
                });
            }
        }
    }
    (
        Finding {
            id: "2a",
            claim: "qbvh_chunks: chunk-root frame faster than parent frame (beyond the measured noise)".into(),
            kilian: "5.2.3, fig. 5.5 left".into(),
            cases: fast,
        },
        Finding {
            id: "2b",
            claim: "qbvh_chunks: parent frame needs fewer triangle tests per ray".into(),
            kilian: "5.2.3, fig. 5.5 right".into(),
            cases: tests,
        },
    )
}

fn find<'c, 'a>(c: &'c Case<'a>, layout: &str, want: &[(&str, &str)]) -> Option<&'c Point<'a>> {
    c.points
        .iter()
        .find(|p| p.layout == layout && want.iter().all(|(k, v)| p.params.get(*k).is_none_or(|x| x == v)))
}

/// Kilian's chosen qbvh_chunks (5.2.3): 64-byte chunks, chunk-root frame, 8 bits.
fn default_qbvh_chunks<'c, 'a>(c: &'c Case<'a>) -> Option<&'c Point<'a>> {
    find(c, "qbvh_chunks", &[("chunk_bytes", "64"), ("frame", "chunk"), ("bits", "8")])
}

fn octree_pair(cases: &[Case]) -> Finding {
    let mut out = Vec::new();
    for c in cases {
        let Some(o) = find(c, "octree", &[]) else { continue };
        let Some(o1) = find(c, "octree_1bit", &[("chunk_bytes", "16"), ("fill", "bfs")]) else { continue };
        let (Some(so), Some(s1)) = (speed(o.row), speed(o1.row)) else { continue };
        if degenerate(o.row) || degenerate(o1.row) {
            out.push(not_applicable(c.label.clone(), &[o.row, o1.row]));
            continue;
        }
        let ratio = s1.ratio(so);
        out.push(CaseVerdict {
            case: c.label.clone(),
            verdict: at_most(ratio, ALMOST_AS_FAST),
            numbers: format!(
                "octree {}, octree_1bit 16B {}: {}",
                fmt_timed(so, speed_word(o.row)),
                fmt_timed(s1, speed_word(o1.row)),
                fmt_timed(ratio, "x")
            ),
        });
    }
    Finding {
        id: "3",
        claim: format!("octree_1bit (16 B) almost as fast as octree: time ratio <= {ALMOST_AS_FAST} (beyond the measured noise)"),
        kilian: "6.3, fig. 6.2: increase \"only very small\" (Hair: faster)".into(),
        cases: out,
    }
}

fn qbvh_chunks_speed(cases: &[Case]) -> (Finding, Finding) {
    let (mut slower, mut target) = (Vec::new(), Vec::new());
    for c in cases {
        let qs: Vec<&Point> = c.points.iter().filter(|p| p.layout == "qbvh_chunks").collect();
        let slowdown = |p: &Point| {
            p.row.slowdown.filter(|v| v.is_finite()).map(|s| Timed { value: s, spread: p.row.slowdown_spread })
        };
        if let Some(d) = default_qbvh_chunks(c).or(qs.first().copied()) {
            let case = format!("{} ({})", c.label, d.label);
            if slowdown(d).is_some() && degenerate(d.row) {
                slower.push(not_applicable(case, &[d.row]));
            } else if let Some(s) = slowdown(d) {
                // Slower than bvh2: the slowdown above 1 beyond its own noise.
                slower.push(CaseVerdict {
                    case,
                    verdict: match beyond_noise(s, Timed::exact(1.0)) {
                        None => Verdict::WithinNoise,
                        Some(r) if r > 1.0 => Verdict::Agrees,
                        Some(_) => Verdict::Differs,
                    },
                    numbers: format!("slowdown {}", fmt_timed(s, "")),
                });
            }
        }
        let timed: Vec<&Point> = qs.iter().copied().filter(|p| slowdown(p).is_some()).collect();
        let usable: Vec<&Point> = timed.iter().copied().filter(|p| !degenerate(p.row)).collect();
        if usable.is_empty() && !timed.is_empty() {
            target.push(not_applicable(c.label.clone(), &timed.iter().map(|p| p.row).collect::<Vec<_>>()));
            continue;
        }
        let best = usable.iter().filter_map(|p| slowdown(p).map(|s| (s, *p))).min_by(|a, b| a.0.value.total_cmp(&b.0.value));
        if let Some((s, p)) = best {
            let dflt = default_qbvh_chunks(c)
                .and_then(slowdown)
                .map(|s| format!("; Kilian's 64B/chunk/8bit {}", fmt_timed(s, "x")))
                .unwrap_or_default();
            target.push(CaseVerdict {
                case: c.label.clone(),
                verdict: at_most(s, QBVH_CHUNKS_TARGET_SLOWDOWN),
                numbers: format!("best {} {}{dflt}", p.label, fmt_timed(s, "x")),
            });
        }
    }
    (
        Finding {
            id: "4a",
            claim: "qbvh_chunks clearly slower than bvh2 (slowdown > 1 beyond the measured noise)".into(),
            kilian: "6.3, 6.5, fig. 6.7: \"clear increase\"".into(),
            cases: slower,
        },
        Finding {
            id: "4b",
            claim: format!("target: best qbvh_chunks within {QBVH_CHUNKS_TARGET_SLOWDOWN}x of bvh2 (beyond the measured noise)"),
            kilian: "issue 5 target (Kilian: \"can almost keep up\", 6.5)".into(),
            cases: target,
        },
    )
}

fn qbvh_chunks_topology(cases: &[Case]) -> Finding {
    let mut out = Vec::new();
    for c in cases {
        let Some(b) = find(c, "bvh2", &[]) else { continue };
        let Some(bt) = b.row.topology_bytes.filter(|&t| t > 0) else { continue };
        let ratios: Vec<(f64, &Point)> = c
            .points
            .iter()
            .filter(|p| p.layout == "qbvh_chunks")
            .filter_map(|p| p.row.topology_bytes.map(|t| (t as f64 / bt as f64, p)))
            .collect();
        let judged = default_qbvh_chunks(c)
            .and_then(|d| ratios.iter().find(|(_, p)| std::ptr::eq(*p, d)).copied())
            .or_else(|| ratios.iter().copied().min_by(|a, b| a.0.total_cmp(&b.0)));
        let Some((r, p)) = judged else { continue };
        if degenerate(b.row) || degenerate(p.row) {
            out.push(not_applicable(c.label.clone(), &[b.row, p.row]));
            continue;
        }
        let (lo, hi) = ratios.iter().fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x.0), b.max(x.0)));
        out.push(CaseVerdict {
            case: c.label.clone(),
            verdict: if r <= QBVH_CHUNKS_TOPOLOGY_RATIO { Verdict::Agrees } else { Verdict::Differs },
            numbers: format!(
                "{}: {}x bvh2 ({} of {} bits/node); all qbvh_chunks {}..{}x",
                p.label,
                fmt_num(r),
                p.row.topology_bits_per_node.map(fmt_num).unwrap_or_else(|| "n/a".into()),
                b.row.topology_bits_per_node.map(fmt_num).unwrap_or_else(|| "n/a".into()),
                fmt_num(lo),
                fmt_num(hi)
            ),
        });
    }
    Finding {
        id: "5",
        claim: format!("qbvh_chunks topology <= {QBVH_CHUNKS_TOPOLOGY_RATIO}x bvh2 (Kilian's 64B/chunk/8bit, else the smallest)"),
        kilian: "5.2.1: best case 58.67 / 57.45 bits per node (64 / 128 B) vs 256".into(),
        cases: out,
    }
}

fn octree_1bit_bits(cases: &[Case]) -> Finding {
    let mut out = Vec::new();
    for c in cases {
        for p in c.points.iter().filter(|p| p.layout == "octree_1bit" && get(p, "chunk_bytes").as_deref() == Some("16")) {
            let case = format!("{} ({})", c.label, p.label);
            let Some(b) = p.row.topology_bits_per_node.filter(|v| v.is_finite()) else { continue };
            if degenerate(p.row) {
                out.push(not_applicable(case, &[p.row]));
                continue;
            }
            out.push(CaseVerdict {
                case,
                verdict: if b <= OCTREE_1BIT_BITS_16 { Verdict::Agrees } else { Verdict::Differs },
                numbers: format!(
                    "{} bits/node, fill {}",
                    fmt_num(b),
                    p.row.chunk_fill.map(|f| format!("{:.1}%", f * 100.0)).unwrap_or_else(|| "n/a".into())
                ),
            });
        }
    }
    Finding {
        id: "6",
        claim: format!("octree_1bit at 16 B: <= {OCTREE_1BIT_BITS_16} bits per node"),
        kilian: "4.2.2: 2 bits/node best case (full chunks); 16 B worst case 16".into(),
        cases: out,
    }
}

fn fills(cases: &[Case]) -> Finding {
    let mut out = Vec::new();
    for c in cases {
        let q = default_qbvh_chunks(c).or_else(|| find(c, "qbvh_chunks", &[("chunk_bytes", "64")]));
        let o = find(c, "octree_1bit", &[("chunk_bytes", "16"), ("fill", "bfs")]);
        let (Some(q), Some(o)) = (q, o) else { continue };
        let (Some(fq), Some(fo)) = (q.row.chunk_fill, o.row.chunk_fill) else { continue };
        if degenerate(q.row) || degenerate(o.row) {
            out.push(not_applicable(c.label.clone(), &[q.row, o.row]));
            continue;
        }
        out.push(CaseVerdict {
            case: c.label.clone(),
            verdict: if fq < fo { Verdict::Agrees } else { Verdict::Differs },
            numbers: format!("{} {:.1}%, {} {:.1}%", q.label, fq * 100.0, o.label, fo * 100.0),
        });
    }
    Finding {
        id: "7",
        claim: "qbvh_chunks chunks are filled less than octree_1bit chunks".into(),
        kilian: "6.3, fig. 6.3 (qbvh_chunks < 10%, octree_1bit ~30%)".into(),
        cases: out,
    }
}

/// Kilian's qualitative claims, checked per case. Memory claims use one ray set only (they do not
/// depend on rays).
pub fn findings(rows: &[ResultRow]) -> Vec<Finding> {
    let cs = cases(rows);
    // Memory does not depend on the ray set: judge it on the first case per (scene, chain).
    let mut mem_cases: Vec<Case> = Vec::new();
    for c in &cs {
        if !mem_cases.iter().any(|m| m.scene_name == c.scene_name && m.chain == c.chain) {
            let mut m = c.clone();
            if let Some(k) = &c.rays_kind {
                m.label = m.label.trim_end_matches(&format!(" · {k}")).to_string();
            }
            mem_cases.push(m);
        }
    }
    let (f2a, f2b) = frames(&cs);
    let (f4a, f4b) = qbvh_chunks_speed(&cs);
    vec![
        smaller_chunks(&mem_cases, "octree_1bit", "smaller"),
        smaller_chunks(&cs, "octree_1bit", "faster"),
        smaller_chunks(&mem_cases, "qbvh_chunks", "smaller"),
        smaller_chunks(&cs, "qbvh_chunks", "faster"),
        f2a,
        f2b,
        octree_pair(&cs),
        f4a,
        f4b,
        qbvh_chunks_topology(&mem_cases),
        octree_1bit_bits(&mem_cases),
        fills(&mem_cases),
    ]
}
